"""Stepping a MuJoCo model between communication points (numpy and mujoco only).

This runs inside a MuJoCo plant FMU. A communication step ``h`` is taken as
``floor(h/dt + eps)`` substeps of the fixed ``dt`` plus one shorter last substep, so every
step ends exactly at ``t + h``; the inputs are held over the step. The state vector is
``x = [qpos of the listed joints, qvel of the listed joints]``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .stepping import check_step, substeps
from .state import StateReader

#: Most MuJoCo steps of one communication step: a step of a small model costs 1-5 us, so about a
#: second of CPU; a longer communication step is refused (fmi2Discard, nothing changed).
MAX_SUBSTEPS = 200_000

#: Model fields a plant's physical parameters may set (name -> the id kind it is indexed by).
PARAMETER_FIELDS = {"body_mass": "body", "jnt_stiffness": "joint", "dof_damping": "joint",
                    "tendon_stiffness": "tendon", "tendon_damping": "tendon", "actuator_gear": "actuator"}


def load_model(spec: dict, folder):
    """The MjModel of a MuJoCo plant spec, with its integrator and timestep enforced."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(Path(folder) / spec["model"]))
    model.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{spec.get('integrator', 'RK4')}")
    model.opt.timestep = float(spec["timestep"])
    return model


def _object(model, kind: str, name: str) -> int:
    import mujoco

    obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "joint": mujoco.mjtObj.mjOBJ_JOINT,
           "tendon": mujoco.mjtObj.mjOBJ_TENDON, "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR}[kind]
    i = mujoco.mj_name2id(model, obj, name)
    if i < 0:
        raise ValueError(f"the MJCF model has no {kind} named {name!r}")
    return i


def parameter_address(model, target: str) -> tuple:
    """Where ``"field:name"`` is in the model: ``(field, index)``, the element ``index`` of the flat
    array ``field`` (a joint's ``dof_damping`` is its first dof's; an actuator's ``actuator_gear`` the
    first of its row)."""
    field, _, name = target.partition(":")
    i = _object(model, PARAMETER_FIELDS[field], name)
    if field == "dof_damping":
        i = int(model.jnt_dofadr[i])
    arr = getattr(model, field)
    return field, i * arr.shape[1] if arr.ndim == 2 else i


def set_parameter(model, target: str, value: float) -> None:
    """Set ``"field:name"`` (e.g. ``"tendon_stiffness:suspension"``) to ``value``."""
    field, index = parameter_address(model, target)
    getattr(model, field).reshape(-1)[index] = value


def get_parameter(model, target: str) -> float:
    """The current value of ``"field:name"``."""
    field, index = parameter_address(model, target)
    return float(getattr(model, field).reshape(-1)[index])


class MujocoRuntime:
    """A MuJoCo model stepped at communication points.

    Parameters
    ----------
    spec : dict
        The ``[mujoco]`` table: ``model`` (MJCF file), ``timestep``, ``integrator``, ``joints``,
        ``u`` and ``d`` (actuator names), ``C``, ``x0``, ``parameters``.
    folder : str or Path
        Where the MJCF file is.
    """

    def __init__(self, spec: dict, folder):
        import mujoco

        self._mj = mujoco
        self.spec = spec
        self.folder = folder
        self.model = load_model(spec, folder)
        self.data = mujoco.MjData(self.model)
        self.dt = float(spec["timestep"])
        joints = [_object(self.model, "joint", j) for j in spec["joints"]]
        self.qadr = np.array([self.model.jnt_qposadr[j] for j in joints])
        self.vadr = np.array([self.model.jnt_dofadr[j] for j in joints])
        self.uid = np.array([_object(self.model, "actuator", a) for a in spec.get("u", [])], dtype=int)
        self.did = np.array([_object(self.model, "actuator", a) for a in spec.get("d", [])], dtype=int)
        self.C = np.array(spec["C"], dtype=float)
        self.n, self.m, self.q, self.p = 2 * len(joints), len(self.uid), len(self.did), self.C.shape[0]
        self.x0 = np.array(spec.get("x0") or np.zeros(self.n), dtype=float)
        self.param_names = list(spec.get("parameters", {}))
        self.params = np.array([get_parameter(self.model, spec["parameters"][k]) for k in self.param_names])
        self.u = np.zeros(self.m)
        self.d = np.zeros(self.q)
        self.reset()

    def apply_parameters(self) -> None:
        """Write the physical parameters into the model."""
        for name, value in zip(self.param_names, self.params):
            set_parameter(self.model, self.spec["parameters"][name], float(value))

    def reset(self) -> None:
        """Back to ``x0`` at time 0."""
        self._mj.mj_resetData(self.model, self.data)
        k = len(self.qadr)
        self.data.qpos[self.qadr] = self.x0[:k]
        self.data.qvel[self.vadr] = self.x0[k:]
        self._mj.mj_forward(self.model, self.data)

    @property
    def x(self) -> np.ndarray:
        """The state ``[qpos, qvel]`` of the listed joints."""
        return np.concatenate([self.data.qpos[self.qadr], self.data.qvel[self.vadr]])

    def y(self) -> np.ndarray:
        """Measured outputs ``C x``."""
        return self.C @ self.x

    def step(self, h: float) -> None:
        """Advance by ``h`` with ``u`` and ``d`` held (substeps of dt and one shorter last one)."""
        check_step(h, {"u": self.u, "d": self.d})
        substeps(h, self.dt, MAX_SUBSTEPS, "MuJoCo steps")           # refuses a step of too many, nothing changed
        self.data.ctrl[self.uid] = self.u
        self.data.ctrl[self.did] = self.d
        t_end = self.data.time + h
        full = int(math.floor(h / self.dt + 1e-9))
        rest = h - full * self.dt
        if full:
            self._mj.mj_step(self.model, self.data, full)
        if rest > 1e-9 * self.dt:
            self.model.opt.timestep = rest
            self._mj.mj_step(self.model, self.data)
            self.model.opt.timestep = self.dt
        self.data.time = t_end

    def get_state(self) -> dict:
        """JSON-ready state.

        Returns
        -------
        dict
            The MjData fields ``qpos``, ``qvel``, ``act``, ``ctrl``, ``time`` and the runtime's
            ``x0``, ``params``, ``u``, ``d``, as Python floats (a JSON round trip is exact).
        """
        d = self.data
        return {"qpos": d.qpos.tolist(), "qvel": d.qvel.tolist(), "act": d.act.tolist(), "ctrl": d.ctrl.tolist(),
                "time": float(d.time), "x0": self.x0.tolist(), "params": self.params.tolist(),
                "u": self.u.tolist(), "d": self.d.tolist()}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state`, after checking every field (nothing changes otherwise).

        Parameters
        ----------
        state : dict
            Exactly the keys of :meth:`get_state`: ``qpos`` (nq), ``qvel`` (nv), ``act`` (na),
            ``ctrl`` (nu), ``x0`` (n) and ``params`` (one per physical parameter) finite numbers;
            ``time`` a finite number >= 0 (the runtime starts at 0 and only advances);
            ``u`` (m) and ``d`` (q) numbers (inputs may be non-finite, as through fmi2SetReal:
            the step refuses them).

        Raises
        ------
        StateRejected
            For a missing or unknown field, or one of the wrong type, length or value (named).
        """
        r = StateReader(state, ("qpos", "qvel", "act", "ctrl", "time", "x0", "params", "u", "d"), "MuJoCo plant")
        m = self.model
        time = r.number("time", 0.0)
        new = {"qpos": r.vector("qpos", m.nq), "qvel": r.vector("qvel", m.nv), "act": r.vector("act", m.na),
               "ctrl": r.vector("ctrl", m.nu), "x0": r.vector("x0", self.n),
               "params": r.vector("params", len(self.param_names)),
               "u": r.vector("u", self.m, finite=False), "d": r.vector("d", self.q, finite=False)}
        d = self.data
        self.params[:] = new["params"]
        self.apply_parameters()
        d.qpos[:], d.qvel[:], d.ctrl[:] = new["qpos"], new["qvel"], new["ctrl"]
        if m.na:
            d.act[:] = new["act"]
        d.time = time
        self.x0 = new["x0"]
        self.u[:], self.d[:] = new["u"], new["d"]
        self._mj.mj_forward(self.model, d)
