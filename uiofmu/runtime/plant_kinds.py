"""The kinds of plant an FMU carries, one descriptor each (the runtime side; the problem-file side is
:mod:`uiofmu.plant_kinds`).

A plant kind (:class:`PlantKind`) says which key of a plant's data marks it, how its runtime starts from an
FMU's ``model.json``, which ports it declares and with which values, and the C kernel that packs it (or why
there is none). ``linear``: ``x+ = A x + B u + E d`` (or its exact sampling), :mod:`uiofmu.runtime.plant_runtime`;
``switched``: one linear mode per step, picked by its rule (:mod:`uiofmu.runtime.switching`); ``lpv``: matrices
affine in a scheduling parameter theta (:mod:`uiofmu.runtime.lpv`); ``parametric``: unknown constant parameters
theta entering through ``D(y) theta`` (:mod:`uiofmu.runtime.parametric_plant`); ``mujoco``: a MuJoCo model
stepped inside the FMU (:mod:`uiofmu.runtime.mujoco_runtime`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .lpv import LpvPlantRuntime
from .mujoco_runtime import MujocoRuntime
from .parametric_plant import ParametricPlantRuntime
from .plant_runtime import PlantRuntime
from .ports import lpv_plant_ports, parametric_plant_ports, plant_ports
from .switching import SwitchedPlantRuntime

#: The value of ``kind`` in a plant FMU's ``model.json`` whose data is under ``plant``.
PLANT_FMU = "plant"


def _plant_runtime(runtime: type) -> Callable:
    """``start(spec, resources)`` of a kind whose runtime reads ``spec["plant"]`` (labels from ``spec["labels"]``)."""
    def start(spec: dict, resources: str):
        return runtime(spec["plant"]), None, spec.get("labels")
    return start


def _mujoco_runtime(spec: dict, resources: str):
    return MujocoRuntime(spec["mujoco"], resources), spec["mujoco"].get("parameters", {}), None


def _linear_ports(rt, physical: list) -> list:
    return plant_ports(rt.n, rt.u.shape[0], rt.p, rt.d.shape[0], physical, r=rt.r, feeds=_feeds(rt))


def _feeds(rt) -> tuple:
    """The inputs a plant's ``y`` depends on directly: ``"u"`` with a feedthrough ``D``, ``"d"`` with ``F``."""
    return tuple(k for k in ("u", "d") if getattr(rt, {"u": "D", "d": "F"}[k], None) is not None)


def _mujoco_ports(rt, physical: list) -> list:
    """A MuJoCo plant's: a linear plant's without the mismatch (MuJoCo's model has no matrices to perturb)."""
    return plant_ports(rt.n, rt.u.shape[0], rt.p, rt.d.shape[0], physical, mismatch=False, feeds=_feeds(rt))


def _switched_ports(rt, physical: list) -> list:
    return plant_ports(rt.n, rt.u.shape[0], rt.p, rt.d.shape[0], physical, rt.rule)


def _lpv_ports(rt, physical: list) -> list:
    return lpv_plant_ports(rt.n, rt.p, rt.q, rt.s, rt.kind, bool(np.any(rt.parts["D"])))


def _parametric_ports(rt, physical: list) -> list:
    return parametric_plant_ports(rt.n, rt.m, rt.p, rt.params.size)


def _sampled_steps(data: dict) -> tuple:
    """The one step of a discrete plant (its ``dt``); none of its own for a continuous one, which takes every
    step h > 0."""
    return (float(data["dt"]),) if data.get("time") == "discrete" else ()


def _any_step(data: dict) -> tuple:
    """Every step h > 0 (integrated inside the FMU)."""
    return ()


def _no_arrays(rt) -> dict:
    """No arrays besides the plant's own matrices."""
    return {}


def _mismatch_arrays(rt) -> dict:
    return {"mismatch": np.array([rt.mismatch]), "mismatch_seed": np.array([float(rt.mismatch_seed)])}


def _linear_arrays(rt) -> dict:
    return {**_mismatch_arrays(rt), "w_noise": rt.w_noise}


def _switched_arrays(rt) -> dict:
    return {"seed": np.array([float(rt.seed)]), "mode": np.array([float(rt.mode_in)]), **_mismatch_arrays(rt)}


def _lpv_arrays(rt) -> dict:
    return {"theta": rt.theta_in if rt.kind == "input" else None}


def _parametric_arrays(rt) -> dict:
    return {"theta": rt.params.copy()}


@dataclass(frozen=True)
class PlantKind:
    """One kind of plant FMU.

    Attributes
    ----------
    name : str
        Its name (``linear``, ``switched``, ``lpv``, ``parametric``, ``mujoco``).
    key : str or None
        The key of ``[plant]`` (and of the plant's data) that marks it; None for a linear plant (none of
        them). A kind whose FMU is not a ``plant`` one (:attr:`fmu_kind`) has its data under this key instead
        (a MuJoCo plant: ``[mujoco]`` of its spec file, ``mujoco`` of its ``model.json``).
    start : callable
        ``start(spec, resources) -> (runtime, physical parameter targets or None, labels or None)`` from an
        FMU's ``model.json`` and the folder of its resources.
    declare : callable
        ``declare(runtime, physical) -> list of PortSpec``: its ports (``physical``: ``(name, what)`` pairs).
    arrays : callable
        ``arrays(runtime) -> dict``: the runtime's arrays behind its own ports (None: a fresh vector).
    theta_parameters : bool
        Whether its physical parameters are the one parameter port ``theta`` (else one port each).
    c_kernel : str or None
        Its C kernel: the key of :data:`uiofmu.fmu.c_backend.PLANT_KERNELS`, or their prefix when
        :attr:`variant` picks one; None when the C backend has none.
    variant : tuple of str or None
        ``(table, key)`` of the plant data whose value completes the C kernel's key (``<c_kernel>-<value>``).
    python_only : str or None
        Why the C backend has no kernel for it.
    what : str
        What it is, in a C FMU's description.
    fmu_kind : str
        The ``kind`` of its FMU's ``model.json``.
    steps : callable
        ``steps(data) -> tuple``: the step lengths a plant of its data takes; empty when it takes every
        step h > 0 (:mod:`uiofmu.runtime.step_rules`).
    """

    name: str
    key: str | None
    start: Callable
    declare: Callable
    arrays: Callable = _no_arrays
    theta_parameters: bool = False
    c_kernel: str | None = None
    variant: tuple | None = None
    python_only: str | None = None
    what: str = "linear plant"
    fmu_kind: str = PLANT_FMU
    steps: Callable = _sampled_steps


#: The plant kinds, in the order a plant's data is tested for their keys (the first that matches).
PLANT_KINDS = {k.name: k for k in (
    PlantKind("parametric", "parameters", _plant_runtime(ParametricPlantRuntime), _parametric_ports,
              _parametric_arrays, theta_parameters=True, c_kernel="parametric",
              what="plant with unknown parameters"),
    PlantKind("lpv", "scheduling", _plant_runtime(LpvPlantRuntime), _lpv_ports, _lpv_arrays, c_kernel="lpv",
              variant=("theta", "kind"), what="LPV plant"),
    PlantKind("switched", "modes", _plant_runtime(SwitchedPlantRuntime), _switched_ports, _switched_arrays,
              c_kernel="switched", variant=("switching", "rule"), what="switched plant"),
    PlantKind("linear", None, _plant_runtime(PlantRuntime), _linear_ports, _linear_arrays, c_kernel="linear"),
    PlantKind("mujoco", "mujoco", _mujoco_runtime, _mujoco_ports, c_kernel="mujoco", what="MuJoCo plant",
              fmu_kind="mujoco", steps=_any_step),
)}
#: The kind of plant data that has none of the kinds' keys.
LINEAR = PLANT_KINDS["linear"]
#: A MuJoCo plant: its spec's ``[mujoco]`` and its FMU (:mod:`uiofmu.mujoco_plant`).
MUJOCO = PLANT_KINDS["mujoco"]


def data_kind(data: dict) -> PlantKind:
    """The kind of a plant's data (``to_data()`` of a plant, ``model.json``'s ``plant``): the first kind whose
    :attr:`PlantKind.key` it holds, else linear."""
    return next((k for k in PLANT_KINDS.values() if k.fmu_kind == PLANT_FMU and k.key is not None and k.key in data),
                LINEAR)


def fmu_kind(spec: dict) -> PlantKind | None:
    """The plant kind of an FMU's ``model.json``; None for an observer's."""
    if spec["kind"] == PLANT_FMU:
        return data_kind(spec["plant"])
    return next((k for k in PLANT_KINDS.values() if k.fmu_kind == spec["kind"]), None)


__all__ = ["LINEAR", "MUJOCO", "PLANT_FMU", "PLANT_KINDS", "PlantKind", "data_kind", "fmu_kind"]
