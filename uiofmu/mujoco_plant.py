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

import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .runtime.errors import ProblemError
from .runtime.files import parse_toml, read_text
from .runtime.matrices import as_matrix, as_scalar, as_vector
from .runtime.plant_kinds import MUJOCO
from .table import Table
from .runtime.text import MAX_NAME, check_name

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
    doc = parse_toml(read_text(file, "MuJoCo plant spec", error=ProblemError), str(file), error=ProblemError)
    top = Table(doc, "")
    name = check_name(top.get("name", folder.name[:MAX_NAME] or "plant"), "name", ProblemError)
    t = Table(top.get(MUJOCO.key), MUJOCO.key)
    top.get("observer", None), top.get("signals", None)     # copied into the linearised problem file
    top.done()
    model = t.get("model")
    if not isinstance(model, str) or Path(model).name != model or not (folder / model).is_file():
        raise ProblemError(f"mujoco.model: expected the name of the MJCF file in {folder}, found {_short(model)}")
    joints = _names(t.get("joints"), "mujoco.joints", "joint")
    if not joints:
        raise ProblemError("mujoco.joints: name at least one joint")
    n = 2 * len(joints)
    spec = {
        "model": model, "joints": joints,
        "timestep": as_scalar(t.get("timestep", 1e-3), "mujoco.timestep", low=0.0, high=1e-3, open_low=True),
        "integrator": t.choice("integrator", ("RK4", "Euler", "implicit", "implicitfast"), "RK4"),
        "u": _names(t.get("u", []), "mujoco.u", "actuator"), "d": _names(t.get("d", []), "mujoco.d", "actuator"),
        "C": as_matrix(t.get("C"), "mujoco.C", cols=n).tolist(),
        "x0": as_vector(t.get("x0", [0.0] * n), "mujoco.x0", n).tolist(),
        "parameters": _parameters(t.get("parameters", {})),
    }
    t.done()
    if not spec["d"]:
        raise ProblemError("mujoco.d: name at least one actuator for the unknown input")
    from .runtime.mujoco_runtime import MujocoRuntime

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
    return MujocoSpec(name, folder, spec, doc)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:60] + "..."


def _names(value, key: str, what: str) -> list:
    """A list of MJCF object names (printable strings)."""
    if not isinstance(value, list):
        raise ProblemError(f"{key}: expected a list of {what} names, found {_short(value)}")
    return [check_name(v, f"{key}[{i}]", ProblemError) for i, v in enumerate(value)]


def _parameters(value) -> dict:
    """``[mujoco.parameters]``: FMU parameter name (an identifier) -> ``"field:object"``."""
    from .runtime.mujoco_runtime import PARAMETER_FIELDS

    if not isinstance(value, dict):
        raise ProblemError(f"mujoco.parameters: expected a table of name = \"field:object\", found {_short(value)}")
    for name, target in value.items():
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,63}", name) or name in ("x0", "u", "d", "x", "y"):
            raise ProblemError(f"mujoco.parameters.{_short(name)}: a parameter name is a letter followed by letters, "
                               "digits or underscores (at most 64), other than x0, u, d, x, y")
        field, _, obj = target.partition(":") if isinstance(target, str) else ("", "", "")
        if field not in PARAMETER_FIELDS or not obj:
            raise ProblemError(f"mujoco.parameters.{name}: expected \"field:object\" with field one of "
                               f"{', '.join(PARAMETER_FIELDS)}, found {_short(target)}")
        check_name(obj, f"mujoco.parameters.{name}", ProblemError)
    return dict(value)


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

    from .runtime.mujoco_runtime import MujocoRuntime

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


def build_mujoco_plant(spec: MujocoSpec, output, step: float | None = None, backend: str | None = None) -> Path:
    """The MuJoCo plant FMU (the MJCF packed as a resource).

    Parameters
    ----------
    spec : MujocoSpec
    output : str or Path
        The ``.fmu`` file to write.
    step : float, optional
        The step of its ``<DefaultExperiment>`` (none without it).
    backend : {"c", "python"}, optional
        ``c``: MuJoCo's C library steps it, shipped in the FMU (:mod:`uiofmu.fmu.mujoco_c`; no Python where
        it runs); ``python``: pythonfmu with the Python bindings. Default: ``c`` when a C compiler is found.
    """
    from . import __version__
    from .fmu.c_backend import c_compiler
    from .fmu.export import _build_python, model_identifier
    from .runtime.ports import plant_experiment

    ident = model_identifier(spec.name, "plant")
    if (backend or ("c" if c_compiler() else "python")) == "c":
        from .fmu.mujoco_c import build_c_mujoco_plant

        return build_c_mujoco_plant(spec, output, ident, plant_experiment(step) if step else None)
    desc = f"MuJoCo plant {spec.name}, {spec.mujoco['integrator']} substeps of {spec.mujoco['timestep']:g} s " \
           f"(uiofmu {__version__})"
    with tempfile.TemporaryDirectory() as tmp:
        mjcf = Path(tmp) / spec.mujoco["model"]
        shutil.copy2(spec.folder / spec.mujoco["model"], mjcf)
        model = {"kind": "mujoco", "mujoco": spec.mujoco, **({"experiment": plant_experiment(step)} if step else {})}
        return _build_python(model, ident, desc, output, extra_files=[mjcf])
