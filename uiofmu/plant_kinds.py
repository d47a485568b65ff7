"""The kinds of plant a problem file describes, one descriptor each (the problem-file side; what an FMU of
each carries is :mod:`uiofmu.runtime.plant_kinds`).

A plant kind (:class:`PlantKind`) says which table of ``[plant]`` marks it, how that table is parsed, what its
plant FMU is called, which steps that FMU takes, and the message that refuses it to a family that does not
design for it (the families name the kinds they accept: :attr:`uiofmu.runtime.registry.Entry.plants`). Every
other module asks these descriptors rather than compare a kind's name or probe a plant's attributes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .lpv_plant import LpvPlant, parse_lpv
from .parametric_plant import ParametricPlant, parse_parametric
from .plant import Plant
from .runtime import plant_kinds as fmu_kinds
from .runtime.errors import ProblemError
from .runtime.registry import FAMILIES
from .switched_plant import SwitchedPlant, parse_switched


def _parse_linear(pt) -> Plant:
    """A linear plant from ``[plant]`` (``A, C, E`` and optional ``B, dt, w, x0, W, D, F``)."""
    time = pt.choice("time", ("continuous", "discrete"))
    if pt.has("switching"):
        raise ProblemError("plant.switching: a switching rule needs the plant's [[plant.modes]]")
    if time == "discrete" and not pt.has("dt"):
        raise pt.missing("dt", "required for a discrete plant (seconds per step)")
    return Plant.create(pt.get("A"), pt.get("C"), pt.get("E"), pt.get("B", None), time=time, dt=pt.get("dt", None),
                        w=pt.get("w", None), x0=pt.get("x0", None), W=pt.get("W", None),
                        D=pt.get("D", None), F=pt.get("F", None))


def _families(name: str) -> str:
    return " or ".join(f'observer.family = "{e.name}"' for e in FAMILIES.values() if name in e.plants)


def _refuse_switched(family: str) -> str:
    return (f"plant.modes: a switched plant needs a family that designs for switched plants "
            f"({_families('switched')}), found {family!r}")


def _refuse_parametric(family: str) -> str:
    return (f"plant.parameters: a plant with unknown parameters needs {_families('parametric')}, and that family "
            f"such a plant; found {family!r}")


def _refuse_lpv(family: str) -> str:
    return (f"plant.scheduling: an LPV plant needs a family that designs for LPV plants "
            f"({_families('lpv')}), found {family!r}")


def _no_signals(plant) -> tuple:
    """No inputs besides ``u`` and ``d``."""
    return ()


@dataclass(frozen=True)
class PlantKind:
    """One kind of plant of a problem file.

    Attributes
    ----------
    name : str
        Its name, as the registry's entries list it (:attr:`uiofmu.runtime.registry.Entry.plants`).
    plant : type
        The class of its plants.
    parse : callable
        ``parse(table) -> plant`` of the ``[plant]`` :class:`~uiofmu.table.Table`.
    describe : callable
        ``describe(plant) -> str``: what the plant is, in an FMU's description and the command line's report.
    exact : bool
        Whether its continuous-time plant FMU is exact between communication points (else RK4 substeps).
    refusal : callable or None
        ``refusal(family) -> str``: the message refusing such a plant to ``family`` (one that does not list it);
        None for a kind whose refusal the family's options give.
    exclusive : bool
        Whether a family that designs for it designs for no other kind (its refusal also answers a plant of
        another kind given to such a family).
    signals : callable
        ``signals(plant) -> tuple of str``: the ``[signals]`` besides ``u`` and ``d`` the plant takes as inputs
        (``mode`` of a switched plant whose rule is ``input``, ``theta`` of an LPV plant whose theta is one).
    """

    name: str
    plant: type
    parse: Callable
    describe: Callable
    exact: bool = True
    refusal: Callable | None = None
    exclusive: bool = False
    signals: Callable = _no_signals

    @property
    def fmu(self) -> fmu_kinds.PlantKind:
        """What its plant FMU carries (:class:`uiofmu.runtime.plant_kinds.PlantKind`)."""
        return fmu_kinds.PLANT_KINDS[self.name]

    @property
    def key(self) -> str | None:
        """The table of ``[plant]`` that marks it (None: a linear plant, marked by none)."""
        return self.fmu.key


#: The plant kinds of problem files, in the order a family's refusal is looked for.
PLANT_KINDS = {k.name: k for k in (
    PlantKind("switched", SwitchedPlant, parse_switched,
              lambda p: f"switched linear plant ({len(p.modes)} modes, rule {p.switching['rule']})",
              refusal=_refuse_switched, signals=lambda p: ("mode",) if p.switching.get("rule") == "input" else ()),
    PlantKind("parametric", ParametricPlant, parse_parametric,
              lambda p: f"plant with {p.n_theta} unknown parameter(s) theta (D(y) theta, RK4 substeps, output ydot)",
              False, _refuse_parametric, exclusive=True),
    PlantKind("lpv", LpvPlant, parse_lpv,
              lambda p: f"LPV plant ({len(p.parts)} scheduling component(s), theta from the {p.theta['kind']})",
              refusal=_refuse_lpv, signals=lambda p: ("theta",) if p.theta.get("kind") == "input" else ()),
    PlantKind("linear", Plant, _parse_linear, lambda p: "linear plant"),
)}


def table_kind(pt) -> PlantKind:
    """The kind of a ``[plant]`` table: the first (in :data:`uiofmu.runtime.plant_kinds.PLANT_KINDS` order) whose
    table it holds, else linear."""
    return next((PLANT_KINDS[k.name] for k in fmu_kinds.PLANT_KINDS.values()
                 if k.name in PLANT_KINDS and k.key is not None and pt.has(k.key)), PLANT_KINDS[fmu_kinds.LINEAR.name])


def plant_kind(plant) -> PlantKind:
    """The kind of a plant object (by its class)."""
    return next(k for k in PLANT_KINDS.values() if isinstance(plant, k.plant))


def check_family(kind: PlantKind, family: str) -> None:
    """Refuse a plant of ``kind`` to ``family`` when the family does not design for it (or designs only for a kind
    that is exclusive); ProblemError with the first refusal in :data:`PLANT_KINDS` order."""
    takes = FAMILIES[family].plants
    for k in PLANT_KINDS.values():
        if k.refusal is not None and ((kind is k and k.name not in takes) or
                                      (k.exclusive and k.name in takes and kind is not k)):
            raise ProblemError(k.refusal(family))


__all__ = ["PLANT_KINDS", "PlantKind", "check_family", "plant_kind", "table_kind"]
