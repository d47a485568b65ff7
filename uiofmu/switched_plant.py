"""Switched plants: discrete modes sharing one output matrix, and the rule the plant FMU switches by.

A ``[plant]`` table with ``[[plant.modes]]`` is a switched plant (seed 002)::

    x_{k+1} = A_i x_k + B_i u_k + E_i d_k + w_i,    y_k = C x_k,    i = alpha_k in 1..N

Matrices given at ``[plant]`` level (``A``, ``B``, ``E``, ``w``) are common to every mode; a
mode's table overrides them. ``C`` is common: the observer's identities (paper (10)-(11)) hold
only when the output map is the same before and after a switch, so a mode's own ``C`` is refused.
``[plant.switching]`` says how the plant FMU picks its mode (:mod:`uiofmu.runtime.switching`);
the observer needs only the mode of each step, known in real time.
"""

from __future__ import annotations

from dataclasses import dataclass

from .plant import Plant, period
from .runtime.errors import ProblemError
from .runtime.matrices import as_matrix, as_vector
from .runtime.switching import INT_MAX, INT_MIN, RULES
from .table import Table

#: Most modes of a switched plant (the design has N^2 LMIs, the card N^2 step matrices).
MAX_MODES = 16

#: Keys a mode's table may set.
MODE_KEYS = ("A", "B", "E", "w")


@dataclass(frozen=True)
class SwitchedPlant:
    """A switched discrete plant: its modes (each a :class:`~uiofmu.plant.Plant` with the common
    ``C``, ``dt`` and ``x0``) and its switching rule.

    Attributes
    ----------
    modes : tuple of Plant
    switching : dict
        ``rule`` and its keys, checked (``state`` 1-based and ``thresholds``; ``mode0``;
        ``probabilities`` and ``seed``).
    """

    modes: tuple
    switching: dict

    time = "discrete"
    continuous = False

    def __getattr__(self, name):
        if name in ("C", "dt", "x0", "n", "m", "p", "q"):
            return getattr(self.modes[0], name)
        raise AttributeError(name)

    @property
    def N(self) -> int:
        """Number of modes."""
        return len(self.modes)

    def to_data(self) -> dict:
        """The ``[plant]`` table with every mode written out in full (what the plant FMU runs)."""
        first = self.modes[0]
        return {"time": "discrete", "dt": first.dt, "C": first.C.tolist(), "x0": first.x0.tolist(),
                "modes": [{"A": p.A.tolist(), "B": p.B.tolist(), "E": p.E.tolist(), "w": p.w.tolist()}
                          for p in self.modes],
                "switching": dict(self.switching)}


def _switching(table, n: int, N: int) -> dict:

    sw = Table(table.get("switching", {"rule": "input"}), table.key("switching"))
    rule = sw.choice("rule", RULES)
    out = {"rule": rule}
    if rule == "threshold":
        state = sw.get("state")
        if isinstance(state, bool) or not isinstance(state, int) or not 1 <= state <= n:
            raise ProblemError(f"{sw.key('state')}: expected the 1-based index of a state, 1 to {n}, "
                               f"found {repr(state)[:40]}")
        if sw.has("threshold") == sw.has("thresholds"):
            raise ProblemError(f"{sw.key('threshold')}: give either threshold (two modes) or thresholds "
                               f"(N - 1 increasing values)")
        values = [sw.scalar("threshold")] if sw.has("threshold") else list(sw.vector("thresholds"))
        if len(values) != N - 1 or any(b <= a for a, b in zip(values, values[1:])):
            raise ProblemError(f"{sw.key('thresholds')}: expected {N - 1} increasing values for {N} modes "
                               f"(mode 1 below the first, mode N at or above the last), found {values}")
        out.update(state=state, thresholds=values)
    elif rule == "input":
        mode0 = sw.get("mode0", 1)
        if isinstance(mode0, bool) or not isinstance(mode0, int) or not 1 <= mode0 <= N:
            raise ProblemError(f"{sw.key('mode0')}: expected a mode from 1 to {N}, found {repr(mode0)[:40]}")
        out["mode0"] = mode0
    else:
        probs = list(sw.vector("probabilities", N, [1.0 / N] * N))
        if any(v < 0 for v in probs) or abs(sum(probs) - 1.0) > 1e-9:
            raise ProblemError(f"{sw.key('probabilities')}: expected {N} non-negative numbers summing to 1, "
                               f"found {probs} (sum {sum(probs):.12g})")
        seed = sw.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not INT_MIN <= seed <= INT_MAX:
            raise ProblemError(f"{sw.key('seed')}: expected an integer from {INT_MIN} to {INT_MAX}, "
                               f"found {repr(seed)[:40]}")
        out.update(probabilities=probs, seed=seed)
    sw.done()
    return out


def parse_switched(table) -> SwitchedPlant:
    """A :class:`SwitchedPlant` from the ``[plant]`` table (a :class:`uiofmu.problem.Table`) with
    ``[[plant.modes]]``; reads every key of the table.

    Raises
    ------
    ProblemError
        Naming the key: a continuous time, no or too many modes, a mode's own ``C``, an unknown
        key of a mode, a matrix of the wrong shape, a malformed switching rule.
    """

    time = table.choice("time", ("continuous", "discrete"))
    if time != "discrete":
        raise ProblemError(f'{table.key("time")}: a switched plant is discrete (x_k+1 = A_i x_k + ...); '
                           f'found "{time}": sample it first')
    modes = table.get("modes")
    if not isinstance(modes, list) or not 1 <= len(modes) <= MAX_MODES:
        found = f"{len(modes)} modes" if isinstance(modes, list) else type(modes).__name__
        raise ProblemError(f"{table.key('modes')}: expected 1 to {MAX_MODES} [[plant.modes]] tables, found {found}")
    common = {key: table.get(key, None) for key in MODE_KEYS}
    C, x0 = table.get("C"), table.get("x0", None)
    if not table.has("dt"):
        raise table.missing("dt", "required for a discrete plant (seconds per step)")
    dt = period(table.get("dt"), table.key("dt"))             # common: named at plant level
    plants = []
    for i, raw in enumerate(modes):
        mt = Table(raw, f"{table.key('modes')}[{i}]")
        if mt.has("C"):
            raise ProblemError(f"{mt.key('C')}: a switched plant has one output matrix, plant.C: the observer's "
                               "identities (seed 002, (10)-(11)) need the same C before and after a switch")
        own = {key: mt.get(key, common[key]) for key in MODE_KEYS}
        mt.done(" (a mode sets A, B, E, w; C, dt and x0 are common)")
        for key in ("A", "E"):
            if own[key] is None:
                raise ProblemError(f"{mt.key(key)}: required (in the mode or at plant level)")
        where = {key: mt.key(key) if mt.has(key) else table.key(key) for key in MODE_KEYS}
        n = as_matrix(C, table.key("C")).shape[1]
        as_matrix(own["A"], where["A"], rows=n, cols=n)
        for key in ("B", "E"):
            if own[key] is not None:
                as_matrix(own[key], where[key], rows=n)
        if own["w"] is not None:
            as_vector(own["w"], where["w"], n)
        plants.append(Plant.create(own["A"], C, own["E"], own["B"], time="discrete", dt=dt, w=own["w"], x0=x0,
                                   prefix=mt.name))
    shapes = [(p.B.shape[1], p.E.shape[1]) for p in plants]
    if len(set(shapes)) > 1:
        raise ProblemError(f"{table.key('modes')}: every mode needs the same numbers of known and unknown inputs "
                           f"(columns of B and E), found (m, q) = {shapes}")
    switching = _switching(table, plants[0].n, len(plants))
    return SwitchedPlant(tuple(plants), switching)


def as_switched(plant) -> SwitchedPlant:
    """A switched plant as it is, a discrete :class:`~uiofmu.plant.Plant` as one mode (rule ``input``)."""
    if isinstance(plant, SwitchedPlant):
        return plant
    if plant.continuous:
        raise ProblemError("plant.time: the switched family designs for discrete plants; found a continuous one")
    return SwitchedPlant((plant,), {"rule": "input", "mode0": 1})


__all__ = ["MAX_MODES", "SwitchedPlant", "as_switched", "parse_switched"]
