"""Delayed UIO with parameter identification (Fouka, Nehaoua, Arioui, Mammar, L-CSS 2019; seed 001).

The plant ``x' = A x + B u + D(y) theta``, ``y = C x`` (:mod:`uiofmu.parametric_plant`) has more
unknown parameters than outputs, so ``rank C D(y) < rank D(y)``: the observer augments it with
``m`` delayed copies (8), ``m`` from rule (7), ``n_theta / n_y - 1 <= m < n_theta / n_y``, i.e.
``m = ceil(n_theta / n_y) - 1`` (the seed notes' reading: m = 1 for the example). Its gains and
certificate, in the notation of :mod:`uiofmu.runtime.delayed` (the kernel this family runs on):

* ``H``, ``P``, ``G = P Ba`` from (19)-(21), rational in ``ya``; ``Gamma = Hdot Ca + P Aa`` (23) with the
  analytic ``Hdot`` (it needs ``ydot`` and the delayed ``ydot``).
* The paper's polytope with ``2^(2 n_y)`` vertices does not exist: ``Gamma`` is rational in the outputs,
  their derivatives and their delayed values. The design grids ``Gamma`` honestly instead, over a
  declared *premise family*: ``count`` trajectories of the plant driven by the problem's ``[signals] u``
  (each scaled by a factor drawn in ``premise.scale`` and shifted in time by up to ``premise.shift``
  seconds), simulated with ``premise.theta`` (default: the plant's), ``samples`` points each between
  ``premise.start`` and ``premise.duration``. The start leaves out the start-up transient (default: one
  delay after the largest delay, or half-way to the duration): just after ``t = tau`` the delayed outputs
  are the initial state's, and ``Gamma`` there is far larger than anywhere later (1411 against 93 on the
  example), while the observer is not valid before the start anyway.
* The certificate must cover the family, not only its grid: after the design, LMI (29) is checked at the
  stored ``Q``, ``K`` on *validation families*, the same family with other draws (seeds ``seed + 1``,
  ``seed + 2``, ...), on every point the run-time flag would call valid (rank margin at least the floor,
  ``||Gamma||`` at most the grid's largest). A family with failing points adds them to the design points
  and the design is solved again; the card is verified once a validation family passes without any
  change, and it records the seeds (``premise.validation``), which ``verify`` re-checks.
* LMI (29) for one Lyapunov matrix and one gain on every grid point, with a decay ``beta`` (1/s)::

      Gamma_g' Q + Q Gamma_g - Ca' R' - R Ca + 2 beta Q < 0,   I <= Q <= t I,   [[Q, R], [R', cap^2 I]] >= 0

  (``K = Q^-1 R``; the last LMI is ``R' Q^-1 R <= cap^2 I``, and with ``Q >= I`` it gives ``||K|| <= cap``;
  ``t`` minimised). The certificate holds on the premise set: along
  any trajectory whose ``Gamma`` stays in it, ``||e(t)|| <= sqrt(t) exp(-beta t) ||e(0)||``; not globally,
  and the card says so. The run-time validity flag compares the rank margin with the premise's.
* The noise gain (``noise.gain_y``, :func:`noise_system`): with ``v`` added to the measured ``y`` and the premises
  (``H``, ``Gamma``) at their noise-free values, ``eps = z - z_twin`` follows ``eps' = N eps + (K - N H) va`` and
  ``e - e_twin = E (H va - eps)`` (``va`` the current and delayed noise, ``||va||_2 <= sqrt(m + 1) ||v||_2``). The
  continuous bounded real lemma with ``X = c Q`` at every premise and validation point bounds its l2 gain
  (:func:`uiofmu.noise.continuous_brl_certificate`: ``c`` by a scalar search, no solver). Noise through the
  measured ``ydot`` and through the premises (the Hermite derivative of a noisy delayed ``y`` errs by about
  ``|v| / h``) is not covered, and the card's ``noise.reason`` says so.
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..certificate import Check, certificate, positive_check, rounding_floor
from ..consistency import DETERMINED, Determined, consistency_checks
from ..existence import Condition, Existence
from ..lmi import Lmi, LmiSystem
from ..progress import progress
from ..parametric_plant import ParametricPlant
from ..plant import period
from ..runtime.delayed import MAX_SUBSTEPS, augmented, decoupling, gamma, hermite, stacked
from ..runtime.stepping import substeps
from ..runtime.schedules import StepRejected
from ..runtime.errors import InfeasibleError, ProblemError
from ..runtime.matrices import as_vector
from ..runtime.parametric_plant import ParametricPlantRuntime
from ..runtime.tolerances import IDENTITY_RTOL, LMI_MARGIN, ROUNDING_FACTOR, SEARCH_TOL, VERIFY_FRACTION
from ..structure import rank
from ..table import Table
from ..noise import continuous_brl_certificate, recheck, section as noise_section, stated
from . import Analysis, DesignResult

NAME = "delayed-uio"

#: What the card's ``noise.gain_y`` leaves out, and why it has no other gain (:mod:`uiofmu.noise`).
NOISE_REASON = ("gain_y: continuous time, on the premise grid and validation points, the premises (H, Gamma) at their "
                "noise-free values; not covered: noise through the measured ydot and through the premises "
                "(functions of y, ydot and their delayed values), as the Hermite derivative of a noisy delayed y, of "
                "order |v| / h at the step h, nor thetahat; gain_w, gain_dhat_y: no process noise and no dhat in this "
                "family")

#: What the card's ``noise.gain_y`` bounds (``noise.covers``).
NOISE_COVERS = ("||e - e_twin||_L2[t0, T] <= gain_y ||v||_L2[t0 - max tau, T] + initial_term ||eps(t0)||: v added to "
                "the measured y (and so to its delayed copies), e = x - xhat, e_twin the error of the observer fed the "
                "noise-free y, eps = z - z_twin, t0 >= valid_from; while the premises stay at the points certified")

#: The card's ``noise.certificate.method``.
NOISE_METHOD = ("continuous bounded real lemma with X = c Q (the decay certificate's Q, c the best scale) at the "
                "stored matrices, on the premise grid and the validation families' points")


@dataclass(frozen=True)
class Premise:
    """The trajectory family the design is gridded on (see the module docstring)."""

    signals: str
    count: int
    samples: int
    seed: int
    duration: float
    scale: tuple
    shift: float
    theta: tuple | None
    sigma_floor: float | None = None
    start: float = 0.0

    def to_data(self) -> dict:
        """The card's record of it."""
        return {"signals": self.signals, "count": self.count, "samples": self.samples, "seed": self.seed,
                "duration": self.duration, "scale": list(self.scale), "shift": self.shift,
                "theta": None if self.theta is None else list(self.theta), "sigma_floor": self.sigma_floor,
                "start": self.start}

    def drawn(self, seed: int) -> "Premise":
        """The same family with other draws of scale and shift (a validation family)."""
        return replace(self, seed=seed)


@dataclass(frozen=True)
class Options:
    """Options of the delayed UIO.

    Attributes
    ----------
    delays : tuple of float
        The delays tau_i (s).
    decay : float or "max"
        beta (1/s), the certified decay rate of the error on the premise set.
    premise : Premise
    gain_cap : float
        Bound on ``||K||``: the FMU integrates explicitly, so the gain sets its substep.
    xhat0 : numpy.ndarray or None
    step : float
        The default communication step (s).
    """

    delays: tuple
    decay: object
    premise: Premise
    gain_cap: float
    xhat0: np.ndarray | None
    step: float


#: Most premise points (``count x samples``): each costs a Hermite evaluation and a rank-revealing
#: decomposition (about 1.5 ms), so this is about 30 s of grid; the example uses 1,800.
MAX_PREMISE_POINTS = 20_000
#: Most RK4 substeps of the premise family's simulation (all trajectories at once, about 20 us
#: each: 20 s), and most bytes of its stored signals (three arrays of steps x count x outputs).
MAX_PREMISE_SUBSTEPS, MAX_PREMISE_BYTES = 1_000_000, 512 * 2 ** 20


def simulation_steps(plant: ParametricPlant, duration: float, shortest: float, theta) -> tuple:
    """The premise simulation's step ``delta`` (the input held over it), its steps and RK4 substeps per step
    (the substep of the plant with the premise's ``theta``)."""
    data = plant.to_data()
    data["parameters"]["theta"] = [float(v) for v in theta]
    rt = ParametricPlantRuntime(data)
    delta = min(rt.substep * 4, shortest / 20, duration / 2000)
    return delta, int(math.ceil(duration / delta)), max(1, int(math.ceil(delta / rt.substep)))


def _premise_cost(plant: ParametricPlant, delays: np.ndarray, premise: "Premise", key: str) -> None:
    """Refuse a premise family whose grid or simulation exceeds the limits above, before any work."""
    points = premise.count * premise.samples
    if points > MAX_PREMISE_POINTS:
        raise ProblemError(f"{key}: count x samples = {premise.count} x {premise.samples} = {points} premise points, "
                           f"more than the {MAX_PREMISE_POINTS} a design evaluates (about 1.5 ms each): lower "
                           "premise.count or premise.samples")
    total = premise.duration / min(premise.duration / 2000, float(delays.min()) / 20)   # before any allocation
    if total > MAX_PREMISE_SUBSTEPS:
        raise ProblemError(f"{key}: premise.duration = {premise.duration:g} s with the shortest delay "
                           f"{float(delays.min()):g} s needs {total:.3g} simulation steps (the step is at most a "
                           f"twentieth of the shortest delay), more than {MAX_PREMISE_SUBSTEPS}: shorten the "
                           "premise or lengthen the delays")
    theta = premise.theta if premise.theta is not None else plant.theta
    _, steps, sub = simulation_steps(plant, premise.duration, float(delays.min()), theta)
    size = 3 * 8 * (steps + 1) * premise.count * plant.p
    if steps * sub > MAX_PREMISE_SUBSTEPS or size > MAX_PREMISE_BYTES:
        raise ProblemError(f"{key}: simulating the premise family takes {steps} steps x {sub} RK4 substeps "
                           f"({size / 2 ** 20:.0f} MiB of signals); at most {MAX_PREMISE_SUBSTEPS} substeps and "
                           f"{MAX_PREMISE_BYTES // 2 ** 20} MiB: shorten premise.duration, lower premise.count, or "
                           "slow the plant (its fastest mode sets the substep)")


def parse_options(table, plant) -> Options:
    """Read ``[observer]``: ``delays``, ``decay``, ``premise``, ``gain_cap``, ``xhat0``, ``dt``."""

    if not isinstance(plant, ParametricPlant):
        raise ProblemError('observer.family = "delayed-uio": the plant needs its [plant.parameters] (the unknown '
                           "constant parameters theta and D(y))")
    delays = as_vector(table.get("delays"), table.key("delays"))
    if delays.size == 0 or np.any(delays <= 0) or np.any(np.diff(delays) <= 0):
        raise ProblemError(f"{table.key('delays')}: expected increasing positive delays in s, found {delays.tolist()}")
    decay = table.tunable("decay", "max", low=0.0, open_low=True)
    pt = Table(table.get("premise", {}), table.key("premise"))
    signals = pt.choice("signals", ("u",), "u")
    ints = {}
    for key, default, low, high in (("count", 6, 1, 100), ("samples", 300, 2, 100_000), ("seed", 1, 0, 2 ** 31 - 1)):
        value = pt.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ProblemError(f"{pt.key(key)}: expected an integer from {low} to {high}, found {repr(value)[:40]}")
        ints[key] = value
    duration = pt.scalar("duration", 10.0 * float(delays.max()), low=float(delays.max()), open_low=True)
    scale = as_vector(pt.get("scale", [0.5, 1.5]), pt.key("scale"), 2)
    if not 0 <= scale[0] <= scale[1]:
        raise ProblemError(f"{pt.key('scale')}: expected [low, high] with 0 <= low <= high, found {scale.tolist()}")
    shift = pt.scalar("shift", 10.0, low=0.0)
    theta = pt.get("theta", None)
    theta = None if theta is None else tuple(as_vector(theta, pt.key("theta"), plant.n_theta).tolist())
    floor = pt.scalar("sigma_floor", None, low=0.0, open_low=True) if pt.has("sigma_floor") else None
    tau = float(delays.max())
    start = pt.scalar("start", tau + min(tau, 0.5 * (duration - tau)), low=tau)
    if not start < duration:
        raise ProblemError(f"{pt.key('start')}: {start:g} s must be before premise.duration = {duration:g} s")
    pt.done()
    premise = Premise(signals, ints["count"], ints["samples"], ints["seed"], duration, tuple(scale.tolist()),
                      shift, theta, floor, start)
    _premise_cost(plant, delays, premise, pt.name)
    gain_cap = table.scalar("gain_cap", 1e4, low=0.0, open_low=True)
    xhat0 = table.vector("xhat0", plant.n, None)
    step = period(table.get("dt", 1e-3), table.key("dt"))
    return Options(tuple(delays.tolist()), decay, premise, gain_cap, xhat0, step)


# -- existence ----------------------------------------------------------------------------------
def minimal_delays(n_theta: int, n_y: int) -> int:
    """Rule (7): the integer m with ``n_theta / n_y - 1 <= m < n_theta / n_y``, i.e. ``ceil(n_theta / n_y) - 1``."""
    return max(0, -(-n_theta // n_y) - 1)


def generic_rank(plant: ParametricPlant, copies: int, seed: int = 0) -> int:
    """``rank Ca Da`` with ``copies`` copies of the outputs (the current one and ``copies - 1`` delayed ones) at
    random, independent values: its rank for almost every value of the outputs."""
    ys = np.random.default_rng(seed).normal(size=(copies, plant.p))
    Da, _ = stacked(plant.D0, plant.Dy, ys, np.zeros_like(ys))
    return rank(augmented(plant.C, copies) @ Da)


def delays_needed(plant: ParametricPlant) -> int | None:
    """The fewest delays ``m`` with ``rank Ca Da = n_theta`` at generic outputs (:func:`generic_rank`), or None
    when no number of them gives it (once a copy adds no rank, no further copy does: they are alike)."""
    previous = -1
    for m in range(plant.n_theta):
        r = generic_rank(plant, m + 1)
        if r == plant.n_theta:
            return m
        if r == previous:
            return None
        previous = r
    return None


def _delays_hint(plant: ParametricPlant, delays: tuple, needed: int | None) -> str:
    """``observer.delays`` with ``needed`` delays (the given ones, then spaced by the shortest), or that none helps."""
    if needed is None:
        return ("no number of delays gives rank C D_y = n_theta at generic outputs: theta cannot be identified from "
                "these outputs (measure more, or estimate fewer parameters)")
    step = min(delays) if delays else 0.5
    example = list(delays[:needed]) + [max(delays, default=0.0) + k * step for k in range(1, needed - len(delays) + 1)]
    return (f"observer.delays with m = {needed} delays, e.g. [{', '.join(f'{t:g}' for t in example)}]: rank C D_y = "
            f"{plant.n_theta} = n_theta at generic outputs")


def symbolic_rank_condition(plant: ParametricPlant, copies: int) -> str:
    """When ``Ca Da`` loses rank, as a condition on the signals: the nonzero ``n_theta`` minors, factored
    (sympy), all vanish. Symbols ``y1, y2, ...`` now and ``y1_t1, ...`` delayed by tau_1."""
    import sympy

    p, nt = plant.p, plant.n_theta
    names = [[sympy.Symbol(f"y{i + 1}" + (f"_t{c}" if c else "")) for i in range(p)] for c in range(copies)]

    def exact(M):
        return sympy.Matrix(M.shape[0], M.shape[1], [sympy.nsimplify(float(v), rational=True) for v in M.ravel()])

    blocks = [exact(plant.C) * (exact(plant.D0) + sum((names[c][i] * exact(plant.Dy[i]) for i in range(p)),
                                                     sympy.zeros(plant.n, nt))) for c in range(copies)]
    F = sympy.Matrix.vstack(*blocks)
    from itertools import combinations

    minors = set()
    for rows in combinations(range(F.shape[0]), nt):
        det = sympy.factor(F.extract(list(rows), list(range(nt))).det())
        if det != 0:
            minors.add(det)
    if not minors:
        return "C D_y never has full column rank"
    common = sympy.factor(sympy.gcd_list(list(minors)))
    shown = sorted((str(m) for m in minors), key=len)[:6]
    text = f"rank C D_y < {nt} exactly where all of {', '.join(shown)}" + (" ..." if len(minors) > 6 else "")
    text += " vanish"
    if common != 1:
        text += f" (every minor has the factor {common}: it must not vanish)"
    return text


# -- the premise family ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Grid:
    """The premise grid: per point, ``Gamma``, the rank margin, ``|P Da|``, the time and ``H`` (19)."""

    gammas: np.ndarray
    sigmas: np.ndarray
    decoupling: np.ndarray
    times: np.ndarray
    hs: np.ndarray

    def subset(self, keep: np.ndarray) -> "Grid":
        """The points ``keep`` selects (a mask or indices)."""
        return Grid(self.gammas[keep], self.sigmas[keep], self.decoupling[keep], self.times[keep], self.hs[keep])


def simulate_family(plant: ParametricPlant, signals, theta: np.ndarray, draws, duration: float, shortest: float):
    """The plant from ``x0`` for every ``(scale, shift)`` of ``draws`` at once (RK4, the input held over
    each step of ``delta``, as the plant FMU holds it): times, outputs, their derivatives with the new
    input (right limits) and with the previous one (left limits), shapes (K+1,) and (K+1, runs, p)."""
    delta, steps, sub = simulation_steps(plant, duration, shortest, theta)
    runs = len(draws)
    scale = np.array([s for s, _ in draws])[:, None]
    shift = np.array([h for _, h in draws])
    At, Bt, Ct = plant.A.T, plant.B.T, plant.C.T
    D0th, Dyth = plant.D0 @ theta, plant.Dy @ theta          # D(y) theta = D0 theta + y (Dy theta)

    def f(x, u):
        return x @ At + u @ Bt + D0th + (x @ Ct) @ Dyth

    x = np.tile(plant.x0, (runs, 1))
    T = np.arange(steps + 1) * delta
    Ys, Yd, Yl = (np.zeros((steps + 1, runs, plant.p)) for _ in range(3))
    dt = delta / sub
    u = None
    for k in range(steps + 1):
        before = u
        u = scale * np.array([[sig(T[k] + h) for sig in signals] for h in shift]).reshape(runs, plant.m)
        Ys[k], Yd[k] = x @ Ct, f(x, u) @ Ct
        Yl[k] = Yd[k] if before is None else f(x, before) @ Ct
        if k == steps:
            break
        for _ in range(sub):
            k1 = f(x, u)
            k2 = f(x + dt / 2 * k1, u)
            k3 = f(x + dt / 2 * k2, u)
            k4 = f(x + dt * k3, u)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return T, Ys, Yd, Yl


def premise_grid(problem, delays, premise: Premise) -> Grid:
    """Simulate the premise family (:class:`Premise`) and evaluate ``Gamma`` on its grid (exactly
    from the simulated signals: y and ydot of the plant, delayed ones by cubic Hermite between the
    fine simulation's points)."""
    plant = problem.plant
    theta = np.array(premise.theta if premise.theta is not None else plant.theta)
    c = len(delays) + 1
    Aa, Ca = augmented(plant.A, c), augmented(plant.C, c)
    rng = np.random.default_rng(premise.seed)
    draws = [(rng.uniform(*premise.scale), rng.uniform(0.0, premise.shift)) for _ in range(premise.count)]
    T, Ys, Yd, Yl = simulate_family(plant, problem.u, theta, draws, premise.duration, min(delays))
    gammas, sigmas, dec, times, hs = [], [], [], [], []
    for r in range(premise.count):
        for t in np.linspace(max(premise.start, max(delays) + T[1]), premise.duration, premise.samples):
            pts = [hermite(T, Ys[:, r], Yd[:, r], t - tau, Yl[:, r]) for tau in (0.0,) + tuple(delays)]
            ya, yad = np.array([q[0] for q in pts]), np.array([q[1] for q in pts])
            Da, Dadot = stacked(plant.D0, plant.Dy, ya, yad)
            H, Hdot, sigma = decoupling(Ca, Da, Dadot)
            sigmas.append(sigma)
            times.append(t)
            if H is None:
                gammas.append(np.full((Aa.shape[0],) * 2, np.nan))
                hs.append(np.full(Ca.T.shape, np.nan))
                dec.append(np.inf)
                continue
            gammas.append(gamma(Aa, Ca, H, Hdot))
            hs.append(H)
            P = np.eye(Aa.shape[0]) + H @ Ca
            dec.append(float(np.abs(P @ Da).max() / max(1.0, np.abs(Da).max())))
    return Grid(np.array(gammas), np.array(sigmas), np.array(dec), np.array(times), np.array(hs))


#: The default rank-margin floor, relative to the premise family's median margin: ``Gamma`` grows like
#: ``|ydot| / sigma^2``, and below a third of the median the points carry gradients no moderate gain
#: dominates (the paper's example: |Gamma| up to 5.7e3 at a tenth, 4.6e2 at a third).
FLOOR_FRACTION = 1.0 / 3.0


def sigma_floor(grid: Grid, premise: Premise) -> float:
    """The rank margin below which a premise point is left out of the design and the run-time estimate
    flagged invalid: ``premise.sigma_floor``, by default :data:`FLOOR_FRACTION` of the family's median margin."""
    return premise.sigma_floor if premise.sigma_floor is not None else FLOOR_FRACTION * float(np.median(grid.sigmas))


def _analysis(problem):
    plant, opts = problem.plant, problem.options
    conds = []
    ys = np.random.default_rng(0).normal(size=plant.p)
    D = plant.D(ys)
    r_cd, r_d = rank(plant.C @ D), rank(D)
    conds.append(Condition("rank of the original system", r_cd == r_d, False,
                           f"rank C D(y) = {r_cd} {'=' if r_cd == r_d else '<'} rank D(y) = {r_d} at generic y"
                           + ("" if r_cd == r_d else ": theta cannot be decoupled from the outputs alone"),
                           {"rank_CD": r_cd, "rank_D": r_d}))
    m_min = minimal_delays(plant.n_theta, plant.p)
    m = len(opts.delays)
    needed = delays_needed(plant)
    enough = None if needed is None else max(m_min, needed)      # the fewest delays that do (None: no number)
    ok, extra = m >= m_min, m > (enough or m_min)
    conds.append(Condition("delays from rule (7)", ok, True,
                           f"rule (7): n_theta / n_y - 1 <= m < n_theta / n_y gives m = {m_min} "
                           f"(n_theta = {plant.n_theta}, n_y = {plant.p}); observer.delays gives m = {m}"
                           + ("" if ok else ": too few delays") + (" (more than needed)" if extra else ""),
                           {"m_rule": m_min, "m": m}, hint="" if ok else _delays_hint(plant, opts.delays, enough)))
    copies = m + 1
    conds.append(Condition("augmented system (8)", True, False,
                           f"augmented state of dimension {plant.n * copies}, outputs {plant.p * copies}, "
                           f"parameters {plant.n_theta}", {"n": plant.n * copies, "p": plant.p * copies}))
    if not ok:
        return Existence(NAME, tuple(conds)), None
    r_a = generic_rank(plant, copies)
    full = r_a == plant.n_theta
    conds.append(Condition("rank C D_y at generic outputs", full, True,
                           f"rank C D_y = {r_a} {'=' if full else '<'} n_theta = {plant.n_theta} at generic current "
                           f"and delayed outputs with m = {m}"
                           + ("" if full else f": each copy of the outputs adds at most rank C D(y) = {r_cd}, so theta "
                              "cannot be decoupled on any trajectory"),
                           {"rank_CaDa": r_a, "n_theta": plant.n_theta},
                           hint="" if full else _delays_hint(plant, opts.delays, needed)))
    if not full:
        return Existence(NAME, tuple(conds)), None
    symbolic = symbolic_rank_condition(plant, copies)
    grid = _premise_grid(json.dumps(problem.data, sort_keys=True, default=lambda x: np.asarray(x).tolist()))
    floor = sigma_floor(grid, opts.premise)
    used = grid.sigmas >= floor
    fraction = float(np.mean(~used))
    conds.append(Condition("rank C D_y on the premise family", bool(used.sum() >= 2), True,
                           f"{symbolic}. On the premise family ({opts.premise.count} trajectories x "
                           f"{opts.premise.samples} points) sigma_min(C D_y) ranges from {grid.sigmas.min():.3g} to "
                           f"{grid.sigmas.max():.3g} (median {np.median(grid.sigmas):.3g}); the design uses the points "
                           f"with sigma_min >= {floor:.3g} (premise.sigma_floor) and leaves out "
                           f"{100 * fraction:.1f} %, "
                           "where the observer flags its estimates invalid",
                           {"symbolic": symbolic, "sigma_min": float(grid.sigmas.min()), "sigma_floor": floor,
                            "left_out": fraction}))
    worst = float(grid.decoupling[used].max()) if used.any() else np.inf
    conds.append(Condition("P_y D_y = 0", worst <= IDENTITY_RTOL, True,
                           (f"|P_y D_y| <= {IDENTITY_RTOL:.0e} (relative) on the premise points used: zero to "
                            "rounding" if worst <= IDENTITY_RTOL else
                            f"largest |P_y D_y| on the premise points used: {worst:.3g} (relative), above "
                            f"{IDENTITY_RTOL:.0e}"),
                           {"residual": worst}))
    return Existence(NAME, tuple(conds)), grid.subset(used)


def analyse(problem, solver: bool = True) -> Analysis:
    """Rank of the original system, rule (7), the augmented system, the rank of C D_y (at generic outputs, where a
    refusal names the fewest delays that suffice, then symbolic and on the premise family), P_y D_y = 0."""
    existence, grid = _analysis(problem)
    return Analysis(existence, {"grid": grid})


# -- design -----------------------------------------------------------------------------------
def _lmis(gammas: np.ndarray, Ca: np.ndarray, cap: float) -> LmiSystem:
    N, py = Ca.shape[1], Ca.shape[0]

    def build(v, prm, ops):
        Q, R = v["Q"], v["R"]
        out = [Lmi("Q >= I", Q - ops.eye(N), strict=False), Lmi("Q <= t I", v["t"] * ops.eye(N) - Q, strict=False),
               Lmi("||K|| <= gain_cap", ops.bmat([[Q, R], [R.T, (cap * cap) * ops.eye(py)]]), strict=False)]
        RC = R @ Ca
        for g, G in enumerate(gammas):
            M = G.T @ Q + Q @ G - RC - RC.T + prm["beta2"] * Q
            out.append(Lmi(f"(29) at premise point {g + 1}", -1.0 * M))
        return out

    return LmiSystem(f"{NAME} (29)", {"Q": ("symmetric", N), "R": ("matrix", (N, py)), "t": ("scalar",)},
                     {"beta2": 1.0}, build, objective=lambda v: v["t"], homogeneous=False)


def point_checks(matrices: dict, gammas: np.ndarray, beta: float) -> tuple:
    """LMI (29) at the stored matrices at every premise point: ``eig_min(-(N_g' Q + Q N_g + 2 beta Q))``
    (``N_g = Gamma_g - K Ca``) and the bound each must clear, decided with margin over its rounding as
    :func:`uiofmu.certificate.definite_check` decides one; and the rounding floors."""
    Q, K, Ca = (np.asarray(matrices[k], dtype=float) for k in ("Q", "K", "Ca"))
    N = np.asarray(gammas, dtype=float).reshape(-1, *Q.shape) - (K @ Ca)[None]
    aQ = np.abs(Q)
    M = -(np.swapaxes(N, 1, 2) @ Q[None] + Q[None] @ N + 2 * beta * Q[None])
    M = 0.5 * (M + np.swapaxes(M, 1, 2))
    floor = rounding_floor(M, 2.0 * np.swapaxes(np.abs(N), 1, 2) @ aQ[None] + 2.0 * beta * aQ[None], len(Q) + 3)
    bound = np.maximum(VERIFY_FRACTION * LMI_MARGIN, ROUNDING_FACTOR * floor)
    values = np.linalg.eigvalsh(M)[:, 0] if len(M) else np.zeros(0)
    return values, bound, floor


def checks(matrices: dict, gammas: np.ndarray, beta: float) -> list:
    """The certificate at the stored matrices: ``Q > 0`` and ``-(N_g' Q + Q N_g + 2 beta Q) > 0`` at every
    premise point (``N_g = Gamma_g - K Ca``, :func:`point_checks`), the worst one reported."""
    name = "eig_min of -(N'Q + QN + 2 beta Q) over the premise grid"
    values, bound, floor = point_checks(matrices, gammas, beta)
    if len(values):
        i = int(np.argmin(values - bound))
        worst = Check(name, float(values[i]), float(bound[i]), at_most=False, floor=float(floor[i]))
    else:
        worst = Check(name, -np.inf, 0.0, at_most=False)
    return [positive_check("eig_min(Q)", np.asarray(matrices["Q"], dtype=float)), worst,
            Check("decay rate beta > 0", beta, float(np.finfo(float).tiny), at_most=False)]


def determined(problem, card_data, analysis: Analysis) -> dict:
    """What the card's problem determines: the plant's matrices the FMU integrates (``Abar``,
    ``Bbar``, ``Cbar``, ``D0``, ``Dy``), the augmented ``Ca`` (8), the delays, the step, and the
    schedule's keys other than the substep and the rank-margin bound (:func:`verify` derives those
    from the premise grid)."""
    plant, opts = problem.plant, problem.options
    schedule = card_data["schedule"]
    return {"noise.norm": "l2", "noise.gain_w": None, "noise.gain_dhat_y": None,     # gain_y: verify re-checks it
            "noise.covers": NOISE_COVERS,
            "schedule": {"kind": "continuous", "delays": list(opts.delays), "step": opts.step, "step_policy": "error",
                         "max_substep": schedule.get("max_substep"), "sigma_bound": schedule.get("sigma_bound"),
                         "gamma_bound": schedule.get("gamma_bound"), "valid_from": opts.premise.start},
            **{f"premise.{k}": v for k, v in opts.premise.to_data().items()},
            "decay_bound": None, "overshoot_bound": None,
            **({} if opts.decay == "max" else {"decay_rate": float(opts.decay)}),         # a fixed decay is the card's
            "delays": list(opts.delays), "m": len(opts.delays), "dims.nz": plant.n * (len(opts.delays) + 1),
            "matrices.Abar": plant.A, "matrices.Bbar": plant.B, "matrices.Cbar": plant.C, "matrices.D0": plant.D0,
            "matrices.Dy": plant.Dy, "matrices.Ca": augmented(plant.C, len(opts.delays) + 1)}


def _bound(overshoot: float, beta: float) -> str:
    """The bound the card states, from its overshoot and decay rate."""
    return (f"on the premise set only: ||e(t)|| <= {float(overshoot):.4g} exp(-{float(beta):.4g} t) ||e(0)|| "
            "for trajectories whose Gamma stays in the premise grid's set; not a global certificate")


#: The premise grid's figures come from a long RK4 simulation of the plant: another BLAS kernel's
#: rounding moves them by about 1e-13 (measured), an unstable mode or a long premise more.
PREMISE_RTOL = 1e-6


def substep(gamma_max: float, K: np.ndarray, Ca: np.ndarray) -> float:
    """The FMU's largest RK4 substep: ``h ||Gamma - K Ca|| <= 1`` (inside RK4's stability region),
    with ``||Gamma|| <= gamma_max`` on the premise grid."""
    return 1.0 / max(gamma_max + float(np.linalg.norm(K, 2) * np.linalg.norm(Ca, 2)), 1e-9)


def derived(grid: Grid, K: np.ndarray, Ca: np.ndarray, Q: np.ndarray) -> dict:
    """The card's figures the premise grid (the points the design uses) and the certified ``Q``, ``K``
    determine: the substep, the run-time bounds of the rank margin and of ``||Gamma||``, the premise's
    extremes, ``||K||`` and the overshoot ``sqrt(eig_max(Q) / eig_min(Q))``."""
    gmax = float(max(np.linalg.norm(G, 2) for G in grid.gammas))
    eig = np.linalg.eigvalsh(0.5 * (Q + Q.T))
    return {"schedule.max_substep": substep(gmax, K, Ca), "schedule.sigma_bound": float(grid.sigmas.min()),
            "schedule.gamma_bound": gmax, "premise.sigma_min": float(grid.sigmas.min()), "premise.gamma_max": gmax,
            "premise.points": int(len(grid.gammas)), "gain_norm": float(np.linalg.norm(K, 2)),
            "overshoot": float(np.sqrt(eig[-1] / eig[0]))}


@functools.lru_cache(maxsize=16)
def _premise_grid(problem_json: str) -> Grid:
    """The premise grid of a problem (its canonical JSON: the grid is deterministic, so the analysis, the
    design, ``verify`` and ``build`` in one process simulate it once)."""
    from ..problem import problem_from_data

    problem = problem_from_data(json.loads(problem_json))
    return premise_grid(problem, problem.options.delays, problem.options.premise)


def gain_figures(card_data: dict) -> tuple:
    """The gain ``K``, ``||Ca||`` and the largest ``||Gamma||`` on the premise grid (:mod:`uiofmu.gains`)."""
    m = card_data["matrices"]
    Ca = np.asarray(m["Ca"], dtype=float)
    return [m["K"]], float(np.linalg.norm(Ca, 2)), float(card_data["premise"]["gamma_max"])


def _used_grid(problem_json: str) -> Grid:
    """The premise grid's points the design uses, of a card's problem (its canonical JSON)."""
    from ..problem import problem_from_data

    premise = problem_from_data(json.loads(problem_json)).options.premise
    grid = _premise_grid(problem_json)
    used = grid.sigmas >= sigma_floor(grid, premise)
    return grid.subset(used)


def verify(card) -> list:
    """Re-check the card: the premise grid rebuilt from the card's problem (deterministic), the LMI at
    the stored Q and K on every point, and the figures the grid and the gain determine (:func:`derived`)."""

    key = json.dumps(card.data["problem"], sort_keys=True)
    grid = _used_grid(key)
    m = card.data["matrices"]
    Q, K, Ca = (np.asarray(m[k], dtype=float) for k in ("Q", "K", "Ca"))
    figures = derived(grid, K, Ca, Q) if len(grid.gammas) else {}
    figures = {k: v if isinstance(v, int) else Determined(v, 0.0, PREMISE_RTOL) for k, v in figures.items()}
    text = {"bound": _bound(card.data["overshoot"], card.data["decay_rate"])}    # the text of the figures checked
    seeds, seed = card.data["premise"].get("validation"), card.data["premise"].get("seed")
    if not (isinstance(seeds, list) and 1 <= len(seeds) <= MAX_VALIDATIONS and isinstance(seed, int)
            and seeds == [seed + k for k in range(1, len(seeds) + 1)]):
        return [Check(f"premise.validation (found {str(seeds)[:40]}: seed + 1 .. seed + k, k from 1 to "
                      f"{MAX_VALIDATIONS})" + DETERMINED, math.inf, 0.0)]
    beta = card.data["decay_rate"]
    validated = []
    for k in range(1, len(seeds) + 1):
        name = f"eig_min of -(N'Q + QN + 2 beta Q) over the validation family of seed {seed + k}"
        points = validation_points(key, k, grid).gammas
        check = checks(m, points, beta)[1] if len(points) else Check(name, 0.0, 0.0, at_most=False)
        validated.append(replace(check, name=name))
    noise = recheck(card.data.get("noise"), *noise_system(m, noise_points(key, grid, len(seeds))), continuous=True)
    return (consistency_checks(card.data, figures) + checks(m, grid.gammas, beta) + validated + noise
            + consistency_checks(card.data, text))


def noise_points(problem_json: str, grid: Grid, validations: int) -> Grid:
    """The points the noise gain is certified on: the premise grid's (the points the design uses) and those of the
    validation families ``1 .. validations`` that the run-time flag calls valid (:func:`validation_points`)."""
    parts = [grid] + [validation_points(problem_json, k, grid) for k in range(1, validations + 1)]
    return Grid(*(np.concatenate([getattr(g, f) for g in parts])
                  for f in ("gammas", "sigmas", "decoupling", "times", "hs")))


def noise_system(matrices: dict, points: Grid) -> tuple:
    """The error system from measurement noise at the stored matrices, one point per premise point: stacks
    ``(A, B, C, D)`` for :func:`uiofmu.noise.continuous_brl_checks`.

    With ``v`` added to the measured ``y``, the observer reads ``ya + va`` (``va`` the current and delayed noise)
    and ``z' = N (z - H (ya + va)) + K (ya + va) + P Ba ua``, ``xhat = z - H (ya + va)``, ``N = Gamma - K Ca``.
    With the premises (``H``, ``Gamma``) at their noise-free values, the difference from the noise-free twin,
    ``eps = z - z_twin``, follows::

        eps' = N eps + (K - N H) va,    e - e_twin = -E eps + E H va      (E = [I 0 ... 0]: the plant's block)

    and ``||va||_2 <= sqrt(m + 1) ||v||_2`` (each delayed copy is ``v`` shifted), so the input is taken as
    ``va / sqrt(m + 1)``: ``B = sqrt(m + 1) (K - N H)``, ``D = sqrt(m + 1) E H``, and the l2 gain of these stacks
    bounds ``||e - e_twin||_2 / ||v||_2``.
    """
    K, Ca, C = (np.asarray(matrices[k], dtype=float) for k in ("K", "Ca", "Cbar"))
    copies = Ca.shape[0] // C.shape[0]
    pa, na = Ca.shape
    N = np.asarray(points.gammas, dtype=float).reshape(-1, na, na) - (K @ Ca)[None]
    H = np.asarray(points.hs, dtype=float).reshape(-1, na, pa)
    E = np.eye(C.shape[1], na)
    root = math.sqrt(copies)
    return (N, root * (K[None] - N @ H), np.broadcast_to(-E, (len(N),) + E.shape), root * (E[None] @ H))


def noise_gain(matrices: dict, points: Grid) -> dict:
    """The card's ``noise`` section: ``gain_y`` the least l2 gain that ``X = c Q`` certifies on the points
    (:func:`uiofmu.noise.continuous_brl_certificate` on :func:`noise_system`), what it covers and leaves out."""
    cert = continuous_brl_certificate(*noise_system(matrices, points), matrices["Q"])
    gain, extra, why = stated(cert, NOISE_METHOD)
    return noise_section(gain, "; ".join(([why] if why else []) + [NOISE_REASON]), covers=NOISE_COVERS, **extra)


#: Premise points of the first solve of the cutting-plane design, and most points added per round.
FIRST_POINTS, ADDED_POINTS, MAX_ROUNDS = 40, 40, 15


def first_points(gammas: np.ndarray, count: int) -> list:
    """A spread-out subset: the largest ``Gamma`` first, then each time the point farthest from
    those chosen (farthest-point sampling in the Frobenius norm)."""
    flat = gammas.reshape(len(gammas), -1)
    chosen = [int(np.argmax(np.linalg.norm(flat, axis=1)))]
    dist = np.linalg.norm(flat - flat[chosen[0]], axis=1)
    while len(chosen) < min(count, len(gammas)):
        i = int(np.argmax(dist))
        chosen.append(i)
        dist = np.minimum(dist, np.linalg.norm(flat - flat[i], axis=1))
    return chosen


def grid_margins(Q: np.ndarray, K: np.ndarray, Ca: np.ndarray, gammas: np.ndarray, beta: float) -> np.ndarray:
    """``eig_min(-(N_g' Q + Q N_g + 2 beta Q))`` at every premise point (``N_g = Gamma_g - K Ca``)."""
    N = gammas - (K @ Ca)[None]
    M = -(np.swapaxes(N, 1, 2) @ Q[None] + Q[None] @ N + 2 * beta * Q[None])
    return np.linalg.eigvalsh(0.5 * (M + np.swapaxes(M, 1, 2)))[:, 0]


def solve_on_grid(gammas: np.ndarray, Ca: np.ndarray, cap: float, beta: float):
    """LMI (29) at decay ``beta`` on every premise point, by cutting planes: solve on a spread-out
    subset, check the point found on every point, add the worst violated ones, solve again.

    The LMIs are solved in time scaled by the largest ``|Gamma|`` (``Gamma / s``, ``beta / s``, ``cap / s``:
    the same inequalities divided by ``s``, whose numbers CLARABEL's relative tolerance then suits);
    ``R`` is scaled back, and the check on every point is made in the plant's time.

    Returns
    -------
    (LmiSolution, LmiSystem, int) or (None, LmiSystem, int)
        The verified solution on the last subset (it holds on every point; ``R`` in the plant's time),
        or None when a subset is already infeasible (then so is the whole grid); the system last
        solved; the rounds.
    """
    s = max(float(max(np.linalg.norm(G, 2) for G in gammas)), 1.0)
    active = first_points(gammas, FIRST_POINTS)
    for rounds in range(1, MAX_ROUNDS + 1):
        system = _lmis(gammas[active] / s, Ca, cap / s)
        sol = system.solve(beta2=2 * beta / s)
        if not sol.verified:
            return None, system, rounds
        sol.values["R"] = s * sol.values["R"]
        Q = 0.5 * (sol.values["Q"] + sol.values["Q"].T)
        K = np.linalg.solve(Q, sol.values["R"])
        margins = grid_margins(Q, K, Ca, gammas, beta) / s
        bad = [int(i) for i in np.argsort(margins) if margins[i] < VERIFY_FRACTION * LMI_MARGIN and i not in active]
        if not bad:
            return sol, system, rounds
        active += bad[:ADDED_POINTS]
    return None, system, MAX_ROUNDS


def _certified(gammas, Ca, opts, label):
    """The decay (the requested one, or the fastest by bisection) and its solution."""
    gmax = float(max(np.linalg.norm(G, 2) for G in gammas))
    if opts.decay != "max":
        sol, system, _ = solve_on_grid(gammas, Ca, opts.gain_cap, float(opts.decay))
        if sol is None:
            raise InfeasibleError(f"{label}: LMI (29) has no solution at decay {float(opts.decay):g} 1/s with "
                                  f"||K|| <= gain_cap = {opts.gain_cap:g} on the premise grid (largest |Gamma| "
                                  f"{gmax:.4g}); ask for a slower decay, raise gain_cap, or raise premise.sigma_floor "
                                  "(the points of small rank margin carry the largest Gamma)")
        return float(opts.decay), sol, system, None
    lo, hi, best = 0.0, gmax + opts.gain_cap, None
    solves, started = 0, time.perf_counter()
    with progress(total=None, desc=f"{label}: fastest decay", unit="solve") as bar:
        for beta in [0.01 * gmax] + [None] * 40:
            beta = 0.5 * (lo + hi) if beta is None else beta
            sol, system, rounds = solve_on_grid(gammas, Ca, opts.gain_cap, beta)
            solves += rounds
            bar.update()
            if sol is not None:
                lo, best = beta, (beta, sol, system)
            else:
                hi = beta
            if best and hi - lo <= SEARCH_TOL * max(lo, 1e-12):
                break
    if best is None:
        raise InfeasibleError(f"{label}: LMI (29) has no solution for any decay on the premise grid with ||K|| <= "
                              f"gain_cap = {opts.gain_cap:g} (largest |Gamma| {gmax:.4g}); raise gain_cap or "
                              "premise.sigma_floor")
    return best[0], best[1], best[2], {"parameter": "decay", "solves": solves, "bracket": [lo, hi],
                                       "seconds": time.perf_counter() - started}


#: Most validation families a design draws (each as large as the premise family, and each rebuilt by ``verify``).
MAX_VALIDATIONS = 4


def validation_points(problem_json: str, k: int, grid: Grid) -> Grid:
    """The points of the ``k``-th validation family (the premise family drawn with seed ``seed + k``) that the
    run-time flag calls valid: rank margin at least the design grid's smallest (``sigma_bound``), ``||Gamma||``
    at most its largest (``gamma_bound``)."""
    data = json.loads(problem_json)
    premise = dict(data["observer"].get("premise", {}))
    premise["seed"] = int(premise.get("seed", 1)) + k
    data["observer"]["premise"] = premise
    family = _premise_grid(json.dumps(data, sort_keys=True))
    gmax = float(max(np.linalg.norm(G, 2) for G in grid.gammas))
    size = np.array([np.linalg.norm(G, 2) if np.all(np.isfinite(G)) else np.inf for G in family.gammas])
    keep = (family.sigmas >= float(grid.sigmas.min())) & (size <= gmax)
    return family.subset(keep)


def _failing(matrices: dict, gammas: np.ndarray, beta: float) -> np.ndarray:
    """Which premise points fail the certificate's check of LMI (29) at the stored matrices (:func:`point_checks`)."""
    values, bound, _ = point_checks(matrices, gammas, beta)
    return ~(values >= bound)


def _validated(problem, grid: Grid, Ca: np.ndarray, label: str):
    """The design on the premise grid, then on validation families (:func:`validation_points`) until one passes
    without a change: a family with failing points adds them to the design points, and the design is solved
    again. Returns the decay, its solution and system, the search record, the stored ``Q`` and ``K``, and the
    validation seeds' offsets."""
    opts, key = problem.options, json.dumps(problem.data, sort_keys=True, default=lambda x: np.asarray(x).tolist())
    points = grid.gammas
    for k in range(1, MAX_VALIDATIONS + 1):
        beta, sol, system, searched = _certified(points, Ca, opts, label)
        Q = 0.5 * (sol.values["Q"] + sol.values["Q"].T)
        K = np.linalg.solve(Q, sol.values["R"])
        fresh = validation_points(key, k, grid)
        bad = _failing({"Q": Q, "K": K, "Ca": Ca}, fresh.gammas, beta)
        if not bad.any():
            return beta, sol, system, searched, Q, K, list(range(1, k + 1))
        points = np.concatenate([points, fresh.gammas[bad]])
    raise InfeasibleError(f"{label}: LMI (29) at the design's Q and K fails on fresh draws of the premise family "
                          f"after {MAX_VALIDATIONS} validation families ({int(bad.sum())} of {len(bad)} points of the "
                          f"last, seed {opts.premise.seed + MAX_VALIDATIONS}): the grid does not cover its family; "
                          "raise premise.count or premise.samples, or premise.start past the start-up transient")


def design(problem, analysis: Analysis) -> DesignResult:
    """LMI (29) on the premise grid and its validation families; the kernel's matrices and substep; the card's
    honest bound."""
    plant, opts = problem.plant, problem.options
    grid = analysis.data["grid"]
    copies = len(opts.delays) + 1
    Ca = augmented(plant.C, copies)
    beta, sol, system, searched, Q, K, offsets = _validated(problem, grid, Ca, f"{NAME} design of {problem.name}")
    key = json.dumps(problem.data, sort_keys=True, default=lambda x: np.asarray(x).tolist())
    matrices = {"Q": Q, "K": K, "Ca": Ca, "Abar": plant.A, "Bbar": plant.B, "Cbar": plant.C, "D0": plant.D0,
                "Dy": plant.Dy}
    cert = certificate(sol, checks(matrices, grid.gammas, beta), f"{NAME} design of {problem.name}")
    fig = derived(grid, K, Ca, Q)
    try:
        substeps(opts.step, fig["schedule.max_substep"], MAX_SUBSTEPS, "RK4 substeps of the observer")
    except StepRejected as exc:
        raise ProblemError(f"observer.dt: {exc}") from None
    schedule = {"kind": "continuous", "delays": list(opts.delays), "max_substep": fig["schedule.max_substep"],
                "sigma_bound": fig["schedule.sigma_bound"], "gamma_bound": fig["schedule.gamma_bound"],
                "valid_from": opts.premise.start, "step": opts.step, "step_policy": "error"}
    results = {
        "noise": noise_gain(matrices, noise_points(key, grid, len(offsets))),
        "decay_rate": beta,
        "decay_bound": None, "overshoot_bound": None,
        "overshoot": fig["overshoot"],
        "bound": _bound(fig["overshoot"], beta),
        "premise": {**opts.premise.to_data(), **{k.split(".")[1]: fig[k] for k in fig if k.startswith("premise.")},
                    "validation": [opts.premise.seed + k for k in offsets]},
        "delays": list(opts.delays), "m": len(opts.delays), "gain_norm": fig["gain_norm"],
        "search": searched,
        "design_method": "lmi (29) gridded on the premise family",
    }
    return DesignResult(plant.n * copies, None, schedule, matrices, cert, results, system, opts.xhat0)
