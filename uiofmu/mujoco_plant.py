"""MuJoCo plants: the spec (``plants/NAME/mujoco.toml``), the linearisation, the plant FMU.

A MuJoCo plant folder holds the MJCF model and ``mujoco.toml``::

    name = "quarter-car"
    [mujoco]
    model = "model.xml"          # MJCF, packed into the FMU
    timestep = 0.001             # fixed substep (s); RK4 by default
    joints = ["body_z", "wheel_z"]   # x = [qpos of these, qvel of these]
    u = ["active"]               # actuators driven by the known input
    d = ["road"]                 # actuators driven by the unknown input
    C = [[...]]                  # measured outputs y = C x
    x0 = [...]
    [mujoco.parameters]          # FMU parameters: name = "field:object"
    ks = "tendon_stiffness:suspension"
    [observer] ...               # copied into the generated problem file
    [signals] ...

:func:`linearize` computes the continuous ``(A, B, E)`` from the model's parameters (mass
matrix, joint and tendon stiffness and damping, actuator moments) and cross-checks them
against central finite differences of MuJoCo's accelerations. The model must be linear
around ``qpos = 0`` (slide or hinge joints with springs, no gravity, no contacts).
"""

from __future__ import annotations

import shutil
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ProblemError
from .matrices import as_matrix, as_scalar, as_vector
from .problem import Table

SPEC_FILE = "mujoco.toml"


def is_mujoco_plant(path) -> bool:
    """Whether ``path`` is a MuJoCo plant folder (or its ``mujoco.toml``)."""
    path = Path(path)
    return (path / SPEC_FILE).is_file() if path.is_dir() else path.name == SPEC_FILE


@dataclass(frozen=True)
class MujocoSpec:
    """A checked MuJoCo plant spec."""

    name: str
    folder: Path
    mujoco: dict
    document: dict


def load_spec(path) -> MujocoSpec:
    """Read and check ``mujoco.toml`` (errors name the key)."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    file = folder / SPEC_FILE
    try:
        doc = tomllib.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ProblemError(f"{file}: no such MuJoCo plant spec") from None
    except tomllib.TOMLDecodeError as exc:
        raise ProblemError(f"{file}: not valid TOML ({exc})") from None
    t = Table(doc.get("mujoco"), "mujoco")
    model = t.get("model")
    if not isinstance(model, str) or not (folder / model).is_file():
        raise ProblemError(f"mujoco.model: expected the MJCF file name next to {SPEC_FILE}, found {model!r}")
    joints = t.get("joints")
    if not isinstance(joints, list) or not joints or not all(isinstance(j, str) for j in joints):
        raise ProblemError(f"mujoco.joints: expected a list of joint names, found {joints!r}")
    n = 2 * len(joints)
    spec = {
        "model": model, "joints": joints,
        "timestep": as_scalar(t.get("timestep", 1e-3), "mujoco.timestep", low=0.0, high=1e-3, open_low=True),
        "integrator": t.choice("integrator", ("RK4", "Euler", "implicit", "implicitfast"), "RK4"),
        "u": list(t.get("u", [])), "d": list(t.get("d", [])),
        "C": as_matrix(t.get("C"), "mujoco.C", cols=n).tolist(),
        "x0": as_vector(t.get("x0", [0.0] * n), "mujoco.x0", n).tolist(),
        "parameters": dict(t.get("parameters", {})),
    }
    t.done()
    if not spec["d"]:
        raise ProblemError("mujoco.d: name at least one actuator for the unknown input")
    from .mujoco_runtime import MujocoRuntime

    try:
        import mujoco  # noqa: F401
    except ImportError:
        raise ProblemError(f"{file}: MuJoCo plants need the mujoco package (pip install 'uiofmu[mujoco]')") from None
    try:
        MujocoRuntime(spec, folder)
    except ValueError as exc:
        raise ProblemError(f"{file}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - MuJoCo's own parse errors
        raise ProblemError(f"{folder / model}: MuJoCo cannot load it ({exc})") from None
    return MujocoSpec(doc.get("name", folder.name), folder, spec, doc)


@dataclass(frozen=True)
class Linearization:
    """Continuous ``x' = A x + B u + E d``, ``y = C x`` at the rest position, and its cross-check."""

    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    C: np.ndarray
    fd_A: np.ndarray
    fd_B: np.ndarray
    fd_E: np.ndarray

    @property
    def mismatch(self) -> float:
        """Largest relative difference between the parameter model and the finite differences."""
        pairs = ((self.A, self.fd_A), (self.B, self.fd_B), (self.E, self.fd_E))
        return max(float(np.abs(a - f).max() / max(np.abs(a).max(), 1e-300)) for a, f in pairs if a.size)


def linearize(spec: MujocoSpec, eps: float = 1e-6) -> Linearization:
    """Linearise a MuJoCo plant at ``qpos = qvel = 0``.

    From the parameters: ``M qacc = -(K_j + J_t' k_t J_t) q - (D_j + J_t' c_t J_t) v + F u``
    with the dense mass matrix ``M``, joint stiffness ``K_j`` and damping ``D_j``, tendon
    Jacobians ``J_t`` with stiffness ``k_t`` and damping ``c_t``, and the actuator moments
    ``F`` (``qfrc_actuator`` for a unit control). Cross-check: central differences of
    ``qacc`` from ``mj_forward`` with step ``eps``.
    """
    import mujoco

    from .mujoco_runtime import MujocoRuntime

    rt = MujocoRuntime(spec.mujoco, spec.folder)
    m, d = rt.model, rt.data
    nv = m.nv
    mujoco.mj_resetData(m, d)
    mujoco.mj_forward(m, d)
    Mfull = np.zeros((nv, nv))
    mujoco.mj_fullM(m, d, Mfull)
    K = np.zeros((nv, nv))
    D = np.diag(m.dof_damping.copy())
    for j in range(m.njnt):
        K[m.jnt_dofadr[j], m.jnt_dofadr[j]] += m.jnt_stiffness[j]
    J = np.array(d.ten_J).reshape(m.ntendon, nv) if m.ntendon else np.zeros((0, nv))
    for t in range(m.ntendon):
        K += m.tendon_stiffness[t] * np.outer(J[t], J[t])
        D += m.tendon_damping[t] * np.outer(J[t], J[t])

    def actuator_force(ids):
        F = np.zeros((nv, len(ids)))
        for c, a in enumerate(ids):
            d.ctrl[:] = 0.0
            d.ctrl[a] = 1.0
            mujoco.mj_forward(m, d)
            F[:, c] = d.qfrc_actuator
        d.ctrl[:] = 0.0
        return F

    Fu, Fd = actuator_force(rt.uid), actuator_force(rt.did)
    Minv = np.linalg.inv(Mfull)
    q, v = rt.qadr, rt.vadr
    k = len(q)
    sel = np.ix_(v, v)
    A = np.block([[np.zeros((k, k)), np.eye(k)], [-(Minv @ K)[sel], -(Minv @ D)[sel]]])
    B = np.vstack([np.zeros((k, len(rt.uid))), (Minv @ Fu)[v]])
    E = np.vstack([np.zeros((k, len(rt.did))), (Minv @ Fd)[v]])

    def qacc(qpos, qvel, ctrl):
        mujoco.mj_resetData(m, d)
        d.qpos[q], d.qvel[v], d.ctrl[:] = qpos, qvel, ctrl
        mujoco.mj_forward(m, d)
        return d.qacc[v].copy()

    n, nu = 2 * k, m.nu
    fdA = np.zeros((k, n))
    for i in range(n):
        dx = np.zeros(n)
        dx[i] = eps
        fdA[:, i] = (qacc(dx[:k], dx[k:], np.zeros(nu)) - qacc(-dx[:k], -dx[k:], np.zeros(nu))) / (2 * eps)

    def fd_inputs(ids):
        out = np.zeros((k, len(ids)))
        for c, a in enumerate(ids):
            du = np.zeros(nu)
            du[a] = 1.0
            out[:, c] = (qacc(np.zeros(k), np.zeros(k), du) - qacc(np.zeros(k), np.zeros(k), -du)) / 2.0
        return out

    top = np.hstack([np.zeros((k, k)), np.eye(k)])
    fd_A = np.vstack([top, fdA])
    fd_B = np.vstack([np.zeros((k, len(rt.uid))), fd_inputs(rt.uid)])
    fd_E = np.vstack([np.zeros((k, len(rt.did))), fd_inputs(rt.did)])
    return Linearization(A, B, E, rt.C.copy(), fd_A, fd_B, fd_E)


def problem_document(spec: MujocoSpec, lin: Linearization) -> dict:
    """A problem file (as data) with the linearised plant and the spec's observer and signals."""
    doc = {"name": spec.name,
           "plant": {"time": "continuous", "A": lin.A.tolist(), "B": lin.B.tolist(), "E": lin.E.tolist(),
                     "C": lin.C.tolist(), "x0": list(spec.mujoco["x0"])}}
    for key in ("observer", "signals"):
        if key in spec.document:
            doc[key] = spec.document[key]
    return doc


def build_mujoco_plant(spec: MujocoSpec, output) -> Path:
    """The MuJoCo plant FMU (pythonfmu; the MJCF packed as a resource)."""
    from . import __version__
    from .export import _build_python, model_identifier

    ident = model_identifier(spec.name, "plant")
    desc = f"MuJoCo plant {spec.name}, {spec.mujoco['integrator']} substeps of {spec.mujoco['timestep']:g} s " \
           f"(uiofmu {__version__})"
    with tempfile.TemporaryDirectory() as tmp:
        mjcf = Path(tmp) / spec.mujoco["model"]
        shutil.copy2(spec.folder / spec.mujoco["model"], mjcf)
        return _build_python({"kind": "mujoco", "mujoco": spec.mujoco}, ident, desc, output, extra_files=[mjcf])
