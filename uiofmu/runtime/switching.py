"""Switched plants at run time: the rule that picks the mode, and the plant stepped in it (numpy only).

A switched plant is discrete: over the step from ``t_k`` to ``t_k + dt`` it runs in mode
``alpha_k`` (1..N), ``x+ = A_i x + B_i u + E_i d + w_i`` with ``i = alpha_k``. The plant FMU's
output ``mode`` at ``t_k`` is ``alpha_k``, the mode of the step it is about to take (the observer
takes it as its input ``mode`` at the same point). Rules:

``threshold``
    ``alpha_k = 1 + #{thresholds <= x_k[state]}``: with one threshold, mode 1 while
    ``x[state] < threshold``, else mode 2 (seed 002's rule). A function of the state: no
    feedthrough.
``input``
    ``alpha_k`` is the plant's Integer input ``mode`` (driven by the master's input source).
``random``
    i.i.d. modes with the given probabilities, drawn from a SplitMix64 generator whose state
    is part of the plant's state: ``alpha_k`` is the draw of the generator's k-th output, so a
    run is the same in the Python and the C plant, and after a state restore.
"""

from __future__ import annotations

import numpy as np

from .plant_runtime import INT_MAX, INT_MIN, PlantRuntime
from .refusals import refusal
from .schedules import StepRejected, matches, mode_problem
from .splitmix import MASK, splitmix64
from .state import StateReader
from .stepping import RuntimeInputError, check_step
from .tolerances import STEP_RTOL

#: The rules a switched plant picks its mode by.
RULES = ("threshold", "input", "random")

_MASK = MASK


def draw_mode(output: int, cumulative) -> int:
    """The mode (1..N) of a generator output: the first ``i`` with ``U < cumulative[i]``, where
    ``U = (output >> 11) * 2**-53`` is uniform in [0, 1) and ``cumulative`` the running sums of
    the probabilities (the last mode takes what round-off leaves above the last sum)."""
    u = (output >> 11) * (1.0 / 9007199254740992.0)
    for i, c in enumerate(cumulative[:-1]):
        if u < c:
            return i + 1
    return len(cumulative)


class SwitchedPlantRuntime(PlantRuntime):
    """A switched discrete plant stepped at communication points.

    Parameters
    ----------
    data : dict
        The ``[plant]`` table of a switched plant as data (:meth:`uiofmu.switched_plant.SwitchedPlant.to_data`):
        ``time = "discrete"``, ``dt``, ``C``, ``x0``, ``modes`` (a list of ``{A, B, E, w}``) and
        ``switching`` (``rule`` and its keys: ``state`` (1-based) and ``thresholds``; ``mode0``;
        ``probabilities`` and ``seed``).
    """

    def __init__(self, data: dict):
        sw = data["switching"]
        self.rule = sw["rule"]
        self.state_index = int(sw.get("state", 1)) - 1
        self.thresholds = np.array(sw.get("thresholds", []), dtype=float)
        self.cumulative = np.cumsum(sw.get("probabilities", [1.0])).tolist()
        self.seed = int(sw.get("seed", 0))
        self.mode_in = int(sw.get("mode0", 1))      # the input of rule "input"
        self.drawn = 1
        modes = data["modes"]
        super().__init__({**{k: v for k, v in data.items() if k not in ("modes", "switching")}, **modes[0]})
        n = self.n
        self.modes = [(np.array(md["A"], dtype=float), np.array(md["B"], dtype=float).reshape(n, -1),
                       np.array(md["E"], dtype=float).reshape(n, -1), np.array(md["w"], dtype=float))
                      for md in modes]
        self.N = len(self.modes)
        self._design = self.blocks()

    def blocks(self) -> list:
        """The matrices the mismatch perturbs: ``(A_i, B_i, E_i)`` of every mode, in order."""
        return [mode[:3] for mode in self.modes]

    def _set_blocks(self, blocks: list) -> None:
        self.modes = [(*block, mode[3]) for block, mode in zip(blocks, self.modes)]

    def reset(self) -> None:
        """Back to ``x0``, the generator at its seed."""
        super().reset()
        self.rng = self.seed & _MASK
        self._draw()

    def _draw(self) -> None:
        if self.rule == "random":
            self.rng, out = splitmix64(self.rng)
            self.drawn = draw_mode(out, self.cumulative)

    def mode(self) -> int:
        """``alpha_k``, the mode of the step from the current communication point."""
        if self.rule == "threshold":
            return 1 + int(np.count_nonzero(self.thresholds <= self.x[self.state_index]))
        if self.rule == "random":
            return self.drawn
        return self.mode_in

    def matrices(self, h: float):
        """``(A_i, B_i, E_i, w_i)`` of the current mode for a step of ``dt``."""
        if not matches(h, self.dt, STEP_RTOL):
            raise StepRejected(refusal("plant_off_period", dt=self.dt, h=h))
        return self.modes[self.mode() - 1]

    def step(self, h: float) -> None:
        """Advance by ``dt`` in the current mode (a bad input mode: :class:`RuntimeInputError`)."""
        check_step(h, {"u": self.u, "d": self.d})
        problem = mode_problem(self.mode_in, self.N, "input: mode", "this plant") if self.rule == "input" else None
        if problem:
            raise RuntimeInputError(problem)
        super().step(h)
        self._draw()

    def set_seed(self, seed: int) -> None:
        """A new seed for rule ``random`` (before initialisation; the generator restarts)."""
        self.seed = int(seed)
        self.rng = self.seed & _MASK
        self._draw()

    def get_state(self) -> dict:
        """JSON-ready state: the linear plant's, plus ``mode_in``, ``seed``, ``rng`` and ``drawn``."""
        return {**super().get_state(), "mode_in": self.mode_in, "seed": self.seed, "rng": self.rng,
                "drawn": self.drawn}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` after checking every field (nothing changes otherwise).

        Raises
        ------
        StateRejected
            For a missing, unknown or malformed field (named), a generator state outside
            0..2**64-1 or a drawn mode outside 1..N.
        """
        linear = ("x", "x0", "u", "d", "params", "mismatch", "mismatch_seed")
        r = StateReader(state, (*linear, "mode_in", "seed", "rng", "drawn"), "plant")
        ints = {key: r.integer(key, low, high) for key, low, high in (
            ("mode_in", INT_MIN, INT_MAX), ("seed", INT_MIN, INT_MAX), ("rng", 0, _MASK), ("drawn", 1, self.N))}
        super().set_state({k: state[k] for k in linear})
        self.mode_in, self.seed, self.rng, self.drawn = ints["mode_in"], ints["seed"], ints["rng"], ints["drawn"]
