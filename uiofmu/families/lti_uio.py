"""Classical full-order unknown-input observer (Darouach, Zasadzinski, Xu 1994).

Seed 000, eqs. (2), (5) and Lemma 1: for the sampled plant ``x+ = A x + B u + E d + w``,
``y = C x``::

    z+   = N z + G u + L y + P w,     xhat = z - M y
    M    = -E (CE)^+                  (eq. (5) with Y = 0)
    P    = I + M C,   P E = 0         (exact decoupling)
    N    = P A - K C,  L = K - N M,  G = P B

so that ``e+ = N e``. ``K`` comes from the LMI (Schur form of ``N' X N < rho^2 X``)::

    [[rho^2 X,  (X P A - W C)'],
     [X P A - W C,          X ]]  > 0,    I <= X <= t I,   K = X^{-1} W,

minimising ``t`` (so ``sqrt(t)`` bounds the overshoot), solved in the balanced coordinates of
:mod:`uiofmu.scaling` (``observer.scaling``). ``X >= I`` normalises the otherwise
homogeneous LMI. The certified bound is ``||e_k|| <= sqrt(cond X) rho^k ||e_0||``.
``decay = "max"`` bisects rho between the largest fixed mode (which no K can move: the
invariant zeros) and 1. A continuous plant is designed on its exact sampling at ``dt``.

``method = "riccati"`` needs no solver: ``K`` moves every placeable mode of ``(PA, C)`` inside
the decay (the Kalman gain of the decay-scaled pair, :func:`uiofmu.structure.decay_gain`) and
the discrete Lyapunov equation ``(N/rho)' X (N/rho) - X = -I`` certifies it
(``rho^2 X - N'XN = rho^2 I``). It reaches the weakly observable modes that need gains of
1e3..1e6, where the LMI's normalised variables lose the solver's precision. ``method = "auto"``
(the default) designs with the LMI, which minimises the overshoot bound, and falls back to the
Riccati design when the LMI finds no certificate; the card's ``design_method`` says which one
certified it. With ``observer.gain_cap`` the LMI bounds ``||K||`` (:func:`uiofmu.gains.cap_lmis`) and
``"auto"`` does not fall back (the Riccati gain knows no cap).

**Feedthrough** (``y = C x + D u + F d``, ``[plant] D`` and ``F``): ``D`` alone is a known-input correction. The
observer runs on ``y - D u``: ``xhat = z - M (y - D u)``, ``z+ = N z + L (y - D u) + P B u + P w``, so the card
stores ``G = P B - L D`` and the direct term ``Xu = M D`` of ``xhat`` (the FMU's ``xhat`` then depends on ``u``);
``N``, the conditions and the certificate are those of ``D = 0``. ``F != 0`` changes the decoupling
(:mod:`uiofmu.feedthrough`): ``[H K] [[CE, F], [F, 0]] = [E 0]``, ``M = -H``, with the free gain ``Y`` of
``N = A0 - Y O`` designed as ``K`` is without feedthrough (the same LMI, Riccati and pole placement on the pair
``(A0, O)``); the card's checks add ``MF = 0`` and ``(I+MC)E = LF``. A card with feedthrough has no ``dhat``
(its formula reads ``y_(k+1) - C A xhat_k - C B u_k``, which the feedthrough changes); its residual stays
``r = y - C xhat``, which tends to ``D u + F d``.

**Pole placement** (``observer.poles``): the modes of ``(PA, C)`` (``(A0, O)`` with ``F != 0``) that output
injection moves are placed exactly at the poles given (``scipy.signal.place_poles`` on the observable part of an
orthogonal observability split), the fixed modes stay. With ``N = V diag(lambda) V^-1`` (unit columns of ``V``)
and ``X = (V V^H)^-1`` scaled to ``X >= I``, ``||e_k|| <= cond(V) rho^k ||e_0||`` for ``rho`` the largest modulus of
``N``'s eigenvalues; the card certifies it at ``decay_bound = sqrt(rho^2 + POLE_ROOM)`` rounded up to 4
significant digits (the margin the Lyapunov re-check at the stored matrices needs), with
``overshoot_bound = sqrt(cond X) = cond(V)``. ``poles`` lists ``N``'s eigenvalues. With one output direction the
gain is unique and the overshoot is the problem's; with more, ``place_poles`` picks one of many gains (its
robust algorithm), so the card's ``overshoot_digits`` says the problem does not determine it.

**Reduced order** (``observer.order = "reduced"``): an observer of order ``n - p`` whose gain is designed as ``K``
is (the same LMI or Riccati design, on the reduced decoupled pair) and whose output reconstructs the rest of the
state from ``y``; the construction, its checks and its bound are in :mod:`uiofmu.reduced_order`. The card records
``order`` and stores ``Zx`` (the first step's ``z_0 = Zx (xhat0 - Xy y_0)``).

**Functional** (``observer.functional = L``): the observer of least order (among those searched) estimating the
functionals ``L x`` whatever ``d``, its conditions in the analysis and its card (``order``, ``dims.nf``, ``Lf``,
output ``zhat``) from :mod:`uiofmu.functional_uio`. Its conditions alone decide: the conditions above, which an
observer of the whole state needs, are told as notes (a functional observer exists where ``rank(CE) < rank(E)``
or the decoupled pair is not detectable, when ``L x`` does not see what fails).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..certificate import (
    Check,
    FIGURE_DIGITS,
    certificate,
    round_up,
    decay_check,
    identity_checks,
    lyapunov_check,
    magnitude,
    UNDETERMINED,
    figure_digits,
    overshoot,
    overshoot_check,
    positive_check,
)
from ..decoupling import (
    decoupling_gain,
    detectable,
    identifiability_condition,
    parse_period,
    sampled_decoupling_conditions,
    short_above,
)
from ..consistency import (computed_values, condition, conditioned, dhat_matrices, dhat_record, first,
                           spectrum)
from ..runtime.card import DHAT
from ..runtime.errors import InfeasibleError, ProblemError
from ..existence import Condition, Existence, complex_list, format_complex, from_pairs
from ..lmi import Lmi, LmiSolution, LmiSystem, Tuned, tune
from ..gains import cap_lmis
from ..noise import (NOISE_DECAY_ROOM, NOISE_METHOD, NOISE_OBJECTIVES, NORM, certified, dhat_error_step,
                     fastest_within, gains_section, hinf_norm, least_of, recheck)
from ..reductions import LYAPUNOV, UNCHANGED, UPPER_BOUND, matrix, scalar, symmetric
from ..scaling import SCALINGS, PlantLmis, StateScaling, identity_spread, plant_identity, state_scaling
from ..scaling import to_data as scaling_data
from ..feedthrough import feedthrough_pair
from .. import functional_uio
from ..structure import controllable_split, decay_gain, rank
from ..runtime.tolerances import SEARCH_TOL, ZERO_MARGIN
from ..threads import blas_module
from .. import reduced_order
from . import Analysis, DesignResult

NAME = "lti-uio"


@dataclass(frozen=True)
class Options:
    """Options of the classical UIO.

    Attributes
    ----------
    decay : float or "max"
        Requested contraction factor per step, in (0, 1), or ``"max"`` for the fastest
        certifiable one.
    dt : float
        Design period (the plant's for a discrete plant; ``observer.dt`` for a continuous one).
    xhat0 : numpy.ndarray or None
        Initial estimate (default zeros).
    method : {"auto", "lmi", "riccati"}
        Design method (see the module docstring).
    scaling : {"balance", "none"}
        The coordinates the LMI is solved in (:mod:`uiofmu.scaling`).
    gain_cap : float or None
        Bound on ``||K||_2`` (:mod:`uiofmu.gains`), None for none.
    noise : {"default", "min"}
        ``"min"``: the gain that minimises the noise gain ``gain_y`` at the decay (see :func:`_least_noise`).
    noise_gain : float or None
        The fastest decay whose least-noise gain has a certified ``gain_y`` of at most this (see
        :func:`_fastest_within`), None for none.
    poles : tuple of complex or None
        ``observer.poles``: where to place the assignable modes of the error dynamics (conjugates included), or
        None for a decay design.
    order : {"full", "reduced"}
        ``observer.order``: the full-order observer, or the one of order ``n - p`` (:mod:`uiofmu.reduced_order`).
    functional : numpy.ndarray or None
        ``observer.functional``: the functionals ``L x`` to estimate (:mod:`uiofmu.functional_uio`), None for the
        state.
    """

    decay: object
    dt: float
    xhat0: np.ndarray | None
    method: str = "auto"
    scaling: str = "balance"
    gain_cap: float | None = None
    noise: str = "default"
    noise_gain: float | None = None
    poles: tuple | None = None
    order: str = "full"
    functional: np.ndarray | None = None

    @property
    def step(self) -> float:
        """The communication step a co-simulation takes by default: the design period."""
        return self.dt


#: Design methods: the LMI (least overshoot), the Riccati gain with a Lyapunov certificate, or the
#: LMI with the Riccati design as fallback.
METHODS = ("auto", "lmi", "riccati")


def parse_options(table, plant) -> Options:
    """Read ``[observer]``: ``decay`` (default ``"max"``), ``dt`` (continuous plants), ``xhat0``, ``method``,
    ``scaling``, ``gain_cap``, ``noise``."""
    decay = table.tunable("decay", "max", low=0.0, high=1.0, open_low=True, open_high=True)
    dt = parse_period(table, plant, NAME)
    xhat0 = table.vector("xhat0", plant.n, None)
    order = table.choice("order", ORDERS, "full")
    if order == "reduced" and table.has("functional"):
        raise ProblemError('observer.functional searches the order of the functional observer itself: remove '
                           'observer.order = "reduced" (or observer.functional for the reduced state observer)')
    if order == "reduced":
        _reduced_supported(table, plant)
    method = table.choice("method", METHODS, "auto")
    if method == "riccati" and decay == "max":
        raise ProblemError('observer.method = "riccati" needs a number for observer.decay: it has no fastest decay '
                           '(without fixed modes any decay is reached, with gains that grow without bound); use '
                           'method = "auto" or "lmi" for decay = "max"')
    noise = table.choice("noise", NOISE_OBJECTIVES, "default")
    if noise == "min" and method == "riccati":
        raise ProblemError('observer.noise = "min" designs with the LMI: use method = "auto" or "lmi" (the Riccati '
                           "gain minimises nothing)")
    if plant.feeds_d and noise == "min":
        raise ProblemError(NO_NOISE_DESIGN_WITH_F)
    noise_gain = table.scalar("noise_gain", None, low=0.0, open_low=True)
    if noise_gain is not None and (decay != "max" or method == "riccati" or plant.feeds_d):
        raise ProblemError(f"observer.noise_gain = {noise_gain:g} asks for the fastest decay whose certified gain_y "
                           f"is at most {noise_gain:g}, designed with the least-noise LMI (written for F = 0): leave "
                           f"observer.decay out (or \"max\") and use method = \"auto\" or \"lmi\" (given: decay = "
                           f"{decay!r}, method = {method!r}{', plant.F' if plant.feeds_d else ''})")
    poles = _parse_poles(table) if table.has("poles") else None
    if poles is not None:
        given = [k for k in ("decay", "method", "gain_cap", "noise", "noise_gain") if table.has(k)]
        if given:
            raise ProblemError(f"observer.poles places the error dynamics' poles exactly: remove observer."
                               f"{given[0]} (the decay is the poles' largest modulus)")
    return Options(decay, dt, xhat0, method, table.choice("scaling", SCALINGS, "balance"),
                   table.scalar("gain_cap", None, low=0.0, open_low=True), noise, noise_gain, poles, order=order,
                   functional=functional_uio.parse_option(table, plant))


#: ``observer.order``: the full-order observer, or the reduced one (:mod:`uiofmu.reduced_order`).
ORDERS = ("full", "reduced")


def _reduced_supported(table, plant) -> None:
    """``observer.order = "reduced"`` designs with the decay LMI or the Riccati gain on ``y = C x``: refuse what it
    does not support, naming the key."""
    p, n = plant.C.shape
    if plant.n <= p or rank(plant.C) < p:
        raise ProblemError(f'observer.order = "reduced" needs independent outputs fewer than the states: plant.C is '
                           f"{p} x {n} of rank {rank(plant.C)} (an observer of order n - p = {n - p}); use "
                           'order = "full"')
    given = [f"observer.{k}" for k in ("noise", "noise_gain", "poles") if table.has(k)]
    given += [f"plant.{k}" for k, feeds in (("D", plant.feeds_u), ("F", plant.feeds_d)) if feeds]
    if given:
        raise ProblemError(f'observer.order = "reduced" does not support {given[0]} (it designs the decay LMI or '
                           f"the Riccati gain of a plant without feedthrough): remove {given[0]} or use "
                           f'order = "full"')


#: Most poles a problem file lists.
MAX_POLES = 1000


def _parse_poles(table) -> tuple:
    """``observer.poles``: a list of real poles and ``[re, im]`` pairs (each pair places ``re +- im j``), every
    one inside the unit circle; the poles as complex numbers, conjugates included."""
    raw = table.get("poles")
    key = "observer.poles"
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_POLES:
        raise ProblemError(f"{key}: expected a list of 1 to {MAX_POLES} poles (numbers, or [re, im] pairs for "
                           f"complex conjugates), found {str(raw)[:60]}")
    out = []
    for i, item in enumerate(raw):
        where = f"{key}[{i}]"
        parts = item if isinstance(item, list) else [item]
        numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in parts)
        if len(parts) != (2 if isinstance(item, list) else 1) or not numbers:
            raise ProblemError(f"{where}: expected a number or an [re, im] pair of numbers, found {str(item)[:60]}")
        value = complex(float(parts[0]), float(parts[1]) if len(parts) == 2 else 0.0)
        if not np.isfinite(value) or not abs(value) < 1.0:
            raise ProblemError(f"{where}: the pole {format_complex([value])} has modulus {abs(value):.6g}, expected "
                               "< 1 (a discrete-time error dynamics that converges)")
        if value.imag == 0.0:
            out.append(value)
        else:
            out += [complex(value.real, abs(value.imag)), complex(value.real, -abs(value.imag))]
    return tuple(out)


#: Why a plant whose unknown input feeds through has no least-noise design.
NO_NOISE_DESIGN_WITH_F = ('observer.noise = "min": the least-noise LMI is written for F = 0; a plant whose unknown '
                          "input feeds through (plant.F) has the default design")

def _analysis(problem):
    plant, opts = problem.plant, problem.options
    s = plant.sampled(opts.dt)
    conds, fixed, decouplable = sampled_decoupling_conditions(plant, s, opts.dt)
    if opts.poles is not None and decouplable and detectable(conds):
        conds.append(_poles_condition(opts.poles, fixed, plant.n))
    if opts.poles is None and opts.decay != "max" and decouplable and detectable(conds):
        largest = float(np.abs(fixed).max()) if fixed.size else 0.0
        ok = opts.decay > largest + ZERO_MARGIN
        conds.append(Condition(
            "decay above fixed modes", ok, True,
            f"requested decay {opts.decay:g} > largest fixed mode modulus {largest:.6g}" if ok else
            f"requested decay {opts.decay:g} <= largest fixed mode modulus {largest:.6g}: no gain K moves "
            "that mode, ask for a slower decay or decay = \"max\"",
            {"decay": opts.decay, "largest_fixed_modulus": largest},
            hint="" if ok else _decay_hint(largest)))
    if opts.functional is not None:      # the functional conditions decide; the full-state ones are told
        conds = functional_uio.informational(conds)
        conds.extend(functional_uio.analysis_conditions(s.A, plant.C, s.E, opts.functional,
                                                        1.0 if opts.decay == "max" else float(opts.decay)))
    return Existence(NAME, tuple(conds)), s, fixed


def _poles_condition(poles: tuple, fixed: np.ndarray, n: int) -> Condition:
    """``observer.poles`` lists one pole per assignable mode of the decoupled pair (``n`` minus the fixed modes)."""
    assignable = n - len(fixed)
    ok = len(poles) == assignable
    fixed_text = f"fixed modes {format_complex(fixed)}" if len(fixed) else "no fixed mode"
    msg = (f"{len(poles)} pole(s) given (conjugates counted) for the {assignable} assignable mode(s) of the decoupled "
           f"pair ({n} states, {fixed_text})")
    if not ok:
        msg += ": observer.poles needs exactly one pole per assignable mode (the fixed modes stay where they are)"
    return Condition("poles for the assignable modes", ok, True, msg,
                     {"poles": complex_list(poles), "assignable": assignable, "fixed_modes": complex_list(fixed)})


def _decay_hint(largest: float) -> str:
    """The slowest-change decay to suggest above a fixed mode of modulus ``largest`` (< 1): three digits
    rounded up, unless that reaches 1 (decay lies in (0, 1)), then ``"max"``."""
    value = short_above(largest + ZERO_MARGIN)
    if value < 1.0:
        return f"decay = {value:g}, just slower than the largest fixed mode (or decay = \"max\")"
    return f"decay = \"max\" (the largest fixed mode {largest:.6g} leaves no three-digit decay below 1)"


def analyse(problem, solver: bool = True) -> Analysis:
    """Rank condition, invariant zeros, detectability of ((I+MC)A, C), requested decay."""
    existence, s, fixed = _analysis(problem)
    return Analysis(existence, {"sampled": s, "fixed": fixed})


def _lmis(PA, C, gain_cap: float | None = None, unit=None):
    """The decay LMI, and with ``gain_cap`` the LMIs of ``||X^-1 W|| <= gain_cap`` (:func:`uiofmu.gains.cap_lmis`;
    in the scaled coordinates, whose gain bounds the plant's: ``K = T Ks``, ``T <= I``).

    ``unit`` is the plant's identity in the LMIs' coordinates (:func:`uiofmu.scaling.plant_identity`; the
    identity when None): the normalisations ``X >= I`` and ``X <= t I`` hold in the plant's coordinates, so the
    least ``t`` is the square of the card's overshoot bound. The largest-margin search drops their constants;
    ``t`` reaches it only through the small weight that pins it (:data:`uiofmu.lmi.MARGIN_TIE_BREAK`), so its
    margins can move in their last digits (sampled-data keeps the identity for that reason, see
    docs/tolerances.md).
    """
    n, p = C.shape[1], C.shape[0]

    def build(v, prm, ops):
        X, W, t = v["X"], v["W"], v["t"]
        Y = X @ PA - W @ C
        eye = ops.eye(n) if unit is None else unit
        capped = [] if gain_cap is None else cap_lmis(gain_cap, [("X", X, [("W", W)])], v["s"], ops)
        return [
            Lmi("decay (Schur form of N'XN < rho^2 X)", ops.bmat([[prm["rho2"] * X, Y.T], [Y, X]])),
            Lmi("X >= I", X - eye, strict=False),
            Lmi("X <= t I", t * eye - X, strict=False),
            *capped,
        ]

    variables = {"X": symmetric(n), "W": matrix((n, p)), "t": scalar(UPPER_BOUND if unit is None else UNCHANGED)}
    if gain_cap is not None:
        variables["s"] = scalar()
    return LmiSystem(f"{NAME} decay", variables, {"rho2": 0.98}, build, objective=lambda v: v["t"], homogeneous=True,
                     structure=(PA, C, gain_cap, unit))


def _noise_lmis(PA, C, M, T, sigma: float, gain_cap: float | None = None) -> LmiSystem:
    """The decay LMI and the bounded real lemma of the error system from output noise, with ``g`` bounding
    ``(gain_y / sigma)^2`` (minimised), in the coordinates ``x = diag(T) xs`` of ``PA``, ``C`` and ``M``
    (:class:`uiofmu.scaling.StateScaling`; ``M`` is ``T^-1 M`` of the plant's). The noise is measured in units of
    ``1 / sigma`` (its column of the lemma divided by ``sigma``, the default design's gain), so that ``g`` is
    near 1 whatever the plant's gains.

    Each with its own Lyapunov matrix (``X`` for the decay, ``Z`` for the lemma) and a common slack ``G``
    (de Oliveira, Bernussou and Geromel's extended form: ``G + G' - X <= G X^-1 G'``), the gain
    ``K = G^-1 F``: ``G N = G PA - F C``, ``G B = -G L = G PAM - F (I + CM)`` (``L = K (I + CM) - PAM``), and
    ``e = T eps + T M v`` in the plant's units::

        [[rho^2 X, (GN)'], [GN, G + G' - X]] > 0
        [[Z, 0, (GN)', T], [0, g I, (GB)', (TM)'], [GN, GB, G + G' - Z, 0], [T, TM, 0, I]] > 0
    """
    n, p = C.shape[1], C.shape[0]
    I_CM, PAM, Te, TM = (np.eye(p) + C @ M) / sigma, PA @ M / sigma, np.diag(T), np.diag(T) @ M / sigma

    def build(v, prm, ops):
        X, Z, G, F, g = v["X"], v["Z"], v["G"], v["F"], v["g"]
        GN, GB, GG = G @ PA - F @ C, G @ PAM - F @ I_CM, G + G.T
        capped = [] if gain_cap is None else cap_lmis(gain_cap, [("G", G, [("F", F)])], v["s"], ops)
        return [
            Lmi("decay (extended form of N'XN < rho^2 X)", ops.bmat([[prm["rho2"] * X, GN.T], [GN, GG - X]])),
            Lmi("bounded real lemma (gain_y^2 <= g)", ops.bmat([
                [Z, ops.zeros((n, p)), GN.T, Te],
                [ops.zeros((p, n)), g * ops.eye(p), GB.T, TM.T],
                [GN, GB, GG - Z, ops.zeros((n, n))],
                [Te, TM, ops.zeros((n, n)), ops.eye(n)]])),
            Lmi("X >= I", X - ops.eye(n), strict=False),
            *capped,
        ]

    variables = {"X": symmetric(n), "Z": symmetric(n), "G": matrix((n, n), LYAPUNOV), "F": matrix((n, p)),
                 "g": scalar()}
    if gain_cap is not None:
        variables["s"] = scalar()
    return LmiSystem(f"{NAME} least noise gain", variables, {"rho2": 0.98}, build, objective=lambda v: v["g"],
                     structure=(PA, C, M, T, sigma, gain_cap))


def _noise_point(values: dict) -> dict:
    """A point of :func:`_noise_lmis` as the decay design's: ``X`` and ``W = X K``, ``K = G^-1 F``."""
    X = np.asarray(values["X"], dtype=float)
    return {"X": X, "W": X @ np.linalg.solve(np.asarray(values["G"], dtype=float), values["F"])}


def _noise_system(s, C, M, t, sigma: float, opts: Options) -> tuple:
    """The LMIs of the least noise gain (:func:`_noise_lmis`), compiled once for any decay: in the coordinates
    scaled by ``t`` as the decay's LMIs are and with the noise in units of ``1 / sigma``; its points are mapped back
    to the plant's coordinates by ``back`` and certified by the certificate's checks at the runtime's matrices, as
    every design's.

    Returns
    -------
    tuple
        ``(system, back)``.
    """
    PA = (np.eye(len(M)) + M @ C) @ s.A
    scaling = StateScaling(t)
    Ms = M / np.asarray(t, dtype=float)[:, None]
    system, inverse = scaling.apply(PlantLmis(lambda steps, Cs: _noise_lmis(steps[0].A, Cs, Ms, t, sigma,
                                                                                      opts.gain_cap),
                                              [replace(s, A=PA)], C))
    back = lambda v: _noise_point(scaling.invert(v, inverse))           # noqa: E731
    system.certify = lambda v, prm: all(c.holds for c in checks(_lmi_runtime(s, C, M, back(v)),
                                                                    float(np.sqrt(prm["rho2"]))))
    return system, back


def _least_noise(noise: tuple, s, C, M, rho: float, name: str, gain) -> tuple:
    """``observer.noise = "min"``: the gain of least ``gain_y`` at the decay ``rho`` (a point of the
    ``(system, back)`` of :func:`_noise_system`, re-checked; :func:`uiofmu.noise.least_of`) and its figure
    ``gain(matrices)`` at the runtime's matrices.

    Returns
    -------
    tuple
        ``(figure, solution)``, the solution in the plant's coordinates with its gain ``K``.
    """
    system, back = noise
    found, (sol, matrices, _) = least_of([(system, lambda v: _lmi_runtime(s, C, M, back(v)), "least noise")], rho,
                                         name, gain, parameter="rho2")
    return found, replace(sol, values={**back(sol.values), "K": matrices["K"]})


def noise_options(opts: Options, decay, noise: str) -> Options:
    """These options at another ``decay`` (a number or ``"max"``) with the noise objective ``noise`` (``"default"``
    or ``"min"``), for :mod:`uiofmu.tradeoff`: no ``noise_gain``, and the LMI where the Riccati design has no
    answer (a fastest decay, a least noise gain)."""
    method = "auto" if opts.method == "riccati" and (decay == "max" or noise == "min") else opts.method
    return replace(opts, decay=decay, noise=noise, noise_gain=None, method=method)


def _noise_design(s, C, M, t, rho: float, sol: LmiSolution, system, method: str, opts: Options, name: str) -> tuple:
    """``observer.noise = "min"`` after the default design ``sol`` at ``rho``: the least-noise design at ``rho``
    (with ``decay = "max"`` moved :data:`NOISE_DECAY_ROOM` of the way to 1, where the default point certifies
    too), kept only where its noise gain (the H-infinity norm of its error system) is below the default's.

    Returns
    -------
    tuple
        ``(rho, solution, systems, design_method, record)``, the record saying which design the card holds.
    """
    if opts.decay == "max":
        rho = rho + NOISE_DECAY_ROOM * (1.0 - rho)
    default = hinf_norm(*error_system(_runtime(s, C, M, sol.values["X"], sol.values["K"])))
    record = {"objective": "least gain_y at the decay", "decay": rho, "default_gain_y": default}
    try:
        noise = _noise_system(s, C, M, t, max(default, 1.0), opts)
        found, least = _least_noise(noise, s, C, M, rho, name, lambda m: hinf_norm(*error_system(m)))
        noise_system = noise[0]
    except InfeasibleError as exc:
        return rho, sol, system, method, {**record, "kept": "default", "why": str(exc)[:300]}
    if not found < default:
        return rho, sol, (system, noise_system), method, {**record, "kept": "default", "least_gain_y": found,
                                                           "why": "the least-noise point's gain is not below it"}
    return rho, least, (system, noise_system), NOISE_METHOD, {**record, "kept": "least noise",
                                                                          "least_gain_y": found}


def _fastest_within(s, C, M, t, fastest: float, sol: LmiSolution, system, method: str, opts: Options,
                    name: str) -> tuple:
    """``observer.noise_gain = G``: the fastest decay whose least-noise design (:func:`_least_noise`) has a certified
    ``gain_y`` (the card's figure: :func:`uiofmu.noise.certified` at the runtime's matrices) of at most ``G``.

    The least noise gain does not grow as the decay slows (every point certified at a decay is certified at any
    slower one), so the decay is bisected on the way from ``fastest`` (the default design's ``"max"``) to
    ``uiofmu.noise.NOISE_GAIN_SLOWEST`` of the way to 1 (:func:`uiofmu.noise.fastest_within`, which every family
    shares); the slower end of the bracket is the decay kept.

    Returns
    -------
    tuple
        ``(rho, solution, systems, design_method, record)`` as :func:`_noise_design`.

    Raises
    ------
    InfeasibleError
        When even the slowest decay tried has a larger certified gain (the message gives it).
    """
    goal = float(opts.noise_gain)
    sigma = max(hinf_norm(*error_system(_runtime(s, C, M, sol.values["X"], sol.values["K"]))), 1.0)
    record = {"objective": "fastest decay with gain_y <= noise_gain", "noise_gain": goal, "fastest_decay": fastest}
    noise = _noise_system(s, C, M, t, sigma, opts)

    def least_at(rho: float) -> tuple:
        return _least_noise(noise, s, C, M, rho, name, lambda m: certified(*error_system(m))[0])

    rho, gain, least, search = fastest_within(least_at, fastest, goal, name)
    return rho, least, (system, noise[0]), NOISE_METHOD, {**record, "gain_y": gain, "search": search}


#: The matrices the identities of :func:`checks` that read nothing of the point (without feedthrough) are made of:
#: the same bytes at every point of one design's search.
FIXED_IDENTITIES = ("P", "E_sampled", "M", "C", "B_sampled", "G", "Xy", "Xz", "c", "w_sampled")


def checks(matrices: dict, rho: float, fixed: dict | None = None) -> list:
    """The certificate's checks at the stored matrices (used by the design and by :func:`verify`).

    Decoupling ``(I+MC)E = 0``, the observer identities ``PA - NP - LC = 0``, ``PB = G`` and
    ``c = P w``, the output ``xhat = z - M y`` (``Xz = I``, ``Xy = -M``), the reported gain
    ``K = L + N M``, ``X > 0`` and the decay ``rho^2 X - N'XN > 0``: every matrix the runtime uses
    is checked.

    ``fixed`` (a design's, for the points of its search) keeps the identities that read no matrix of the point
    (decoupling, ``PB = G``, ``P = I + MC``, ``Xy = -M``, ``Xz = I``, ``c = P w``; those of a plant with feedthrough
    read ``L`` and are not kept) by the bytes of the matrices they read (:data:`FIXED_IDENTITIES`): the same
    calls on the same bytes would find the same checks to the last bit.
    """
    g = {k: np.asarray(v, dtype=float) for k, v in matrices.items()}
    P, A, C, N, L = g["P"], g["A_sampled"], g["C"], g["N"], g["L"]
    key = None
    if fixed is not None and "F" not in g and "D" not in g:
        key = tuple((g[k].shape, g[k].tobytes()) for k in FIXED_IDENTITIES)
    same = fixed.get(key) if key is not None else None
    if same is None:
        same = identity_checks(*_fixed_identities(g))
        if key is not None:
            fixed[key] = same
    moving = identity_checks(
        ("||PA - NP - LC||", P @ A - N @ P - L @ C, magnitude([P, A], [N, P], [L, C])),
        ("||K - (L + NM)|| (the gain the card reports)", g["K"] - L - N @ g["M"], magnitude([L], [N, g["M"]])))
    decoupled = 1 + ("F" in g)               # the decoupling checks, then the inputs' and P = I + MC up to ``upto``
    upto = decoupled + 1 + ("D" in g)
    return [*same[:decoupled], moving[0], *same[decoupled:upto + 1], moving[1], *same[upto + 1:],
            positive_check("eig_min(X)", g["X"]),
            lyapunov_check("eig_min(rho^2 X - N'XN)", N, g["X"], rho),
            decay_check(rho)]


def _fixed_identities(g: dict) -> list:
    """The identities of :func:`checks` other than ``PA - NP - LC`` and ``K = L + NM``, in the card's order:
    ``(name, residual, magnitude)``."""
    P, B, E, C, L = g["P"], g["B_sampled"], g["E_sampled"], g["C"], g["L"]
    if "F" in g:         # y = C x + D u + F d: P E = L F and M F = 0 (uiofmu.feedthrough)
        F = g["F"]
        decoupling = [("decoupling ||(I+MC)E - LF||", P @ E - L @ F, magnitude([E], [g["M"], C, E], [L, F])),
                      ("decoupling ||MF||", g["M"] @ F, magnitude([g["M"], F]))]
    else:
        decoupling = [("decoupling ||(I+MC)E||", P @ E, magnitude([E], [g["M"], C, E]))]
    if "D" in g:         # the observer runs on y - D u
        D, G = g["D"], g["G"]
        inputs = [("||PB - LD - G||", P @ B - L @ D - G, magnitude([P, B], [L, D], [G])),
                  ("||Xu - MD||", g["Xu"] - g["M"] @ D, magnitude([g["M"], D]))]
    else:
        inputs = [("||PB - G||", P @ B - g["G"], magnitude([P, B], [g["G"]]) if B.size else 0.0)]
    return [*decoupling, *inputs,
            ("||P - (I + MC)||", P - np.eye(len(P)) - g["M"] @ C, magnitude([g["M"], C])),
            ("||Xy + M||", g["Xy"] + g["M"], magnitude([g["M"]])),
            ("||Xz - I||", g["Xz"] - np.eye(len(P)), 1.0),
            ("||c - P w||", g["c"] - P @ g["w_sampled"], magnitude([P, g["w_sampled"][:, None]]))]


def verify(card) -> list:
    """Re-check a card's certificate from its matrices alone (no solver), the overshoot and the noise gain it claims."""
    d = card.data
    if "nf" in d["dims"] or "Lf" in d["matrices"]:       # a functional observer: zhat estimates Lf x
        return ([*functional_uio.card_checks(d["matrices"], d["decay_bound"]),
                 functional_uio.overshoot_check(d["overshoot_bound"], d["matrices"]),
                 Check("order = dims.nz, the functional observer's state (1: yes)",
                       float(d.get("order") == d["dims"]["nz"]), 1.0, at_most=False)] + noise_checks(d))
    if d.get("order") == "reduced" or "Zx" in d["matrices"]:
        asked = (d.get("problem") or {}).get("observer", {}).get("order", "full")
        return ([Check('the problem asks for observer.order = "reduced" (1: yes)', float(asked == "reduced"), 1.0,
                       at_most=False), *reduced_order.checks(d["matrices"], d["decay_bound"])]
                + [reduced_order.overshoot_check(d["overshoot_bound"], d["matrices"])] + noise_checks(d))
    return (checks(d["matrices"], d["decay_bound"]) + [overshoot_check(d["overshoot_bound"], [d["matrices"]["X"]])]
            + noise_checks(d) + pole_checks(d))


def error_system(matrices: dict) -> tuple:
    """The error system from measurement noise ``v`` (``y = C x + v``) at the stored matrices:
    ``eps+ = N eps - L v``, ``e = Xz eps - Xy v``, with ``eps = Zx x - z`` (``Zx = P`` and ``Xz = I`` for the
    full-order observer; ``Zx A - N Zx - L C = 0``, ``Zx E = 0`` and ``Xz Zx + Xy C = I``, which :func:`checks` and
    :func:`uiofmu.reduced_order.checks` re-check; the known input and the affine term cancel as in ``e+ = N e``).
    A functional observer's ``e = Lf x - zhat`` has the same form with ``Xz Zx + Xy C = Lf``
    (:func:`uiofmu.functional_uio.estimate_output`)."""
    N, L = (np.asarray(matrices[k], dtype=float) for k in ("N", "L"))
    Xz, Xy = functional_uio.estimate_output(matrices)
    return N, -L, Xz, -Xy


def process_error_system(matrices: dict) -> tuple:
    """The error system from process noise ``w`` (``x+ = ... + W_sampled w``): ``eps+ = N eps + Zx W_sampled w``,
    ``e = Xz eps`` (the stored ``Zx`` of the reduced observer, ``P`` of the full-order one)."""
    N, W = (np.asarray(matrices[k], dtype=float) for k in ("N", "W_sampled"))
    Xz = functional_uio.estimate_output(matrices)[0]
    Zx = np.asarray(matrices["Zx"] if "Zx" in matrices else matrices["P"], dtype=float)
    return N, Zx @ W, Xz, np.zeros((Xz.shape[0], W.shape[1]))


def dhat_error_system(matrices: dict) -> tuple:
    """The error system from measurement noise ``v`` to the error of ``dhat``.

    ``dhat_k = Dy (y_(k+1) - Yx xhat_k - Yu u_k - Yc)`` with ``Dy C E = I`` and ``Yx = C A`` gives
    ``dhat_k - d_k = Dy (Yx e_k + v_(k+1))``: it reads the next sample, so in the time ``j = k + 1`` its state is
    ``(eps_(j-1), v_(j-1))``, with ``A = [[N, -L], [0, 0]]``, ``B = [0; I]``, ``C = Dy Yx [Xz, -Xy]``, ``D = Dy``
    (a shift by one step leaves l2 norms as they are): :func:`uiofmu.noise.dhat_error_step` at the stored ``Xz``.
    """
    N, L, Xz, Xy, Dy, Yx = (np.asarray(matrices[k], dtype=float) for k in ("N", "L", "Xz", "Xy", "Dy", "Yx"))
    return dhat_error_step(N, L, Xz, Xy, Dy, Yx)


#: Why an lti-uio card has no process-noise gain.
NO_W = "gain_w: the problem declares no process noise"


def noise_checks(card_data: dict) -> list:
    """The re-check of the noise gains a card states, at its stored matrices."""
    noise, m = card_data.get("noise"), card_data["matrices"]
    out = recheck(noise, *error_system(m))
    if isinstance(noise, dict) and noise.get("gain_w") is not None:
        out += recheck(noise, *process_error_system(m), key="gain_w")
    if isinstance(noise, dict) and noise.get("gain_dhat_y") is not None:
        out += recheck(noise, *dhat_error_system(m), key="gain_dhat_y")
    return out


def noise_section(matrices: dict) -> dict:
    """The card's ``noise`` section (:mod:`uiofmu.noise`): ``gain_y``, and ``gain_w`` where the problem declares
    ``[plant] W``, each by the bounded real lemma at the stored matrices."""
    return gains_section(matrices, lambda: certified(*error_system(matrices)),
                         lambda: certified(*process_error_system(matrices), key="gain_w"),
                         lambda: certified(*dhat_error_system(matrices), key="gain_dhat_y"), NO_W)


def gain_figures(card_data: dict) -> tuple:
    """The gain ``K`` (a functional observer's ``L``, the gain of ``y``), ``||C||`` and ``||A||`` of the sampled plant
    (:mod:`uiofmu.gains`)."""
    m = card_data["matrices"]
    return [m["L"] if "Lf" in m else m["K"]], float(np.linalg.norm(m["C"], 2)), float(np.linalg.norm(m["A_sampled"], 2))


def _dhat(s, C) -> dict:
    """dhat's matrices (``rank(CE) = q``): ``dhat_k = Dy (y_k+1 - Yx xhat_k - Yu u_k - Yc)``, as
    :func:`uiofmu.consistency.dhat_record` records them."""
    return first(dhat_record(C, s.A[None], s.B[None], s.E[None], s.w[None]))


def _schedule(opts: Options) -> dict:
    return {"kind": "constant", "dt": opts.dt, "step_policy": "error"}


#: The bound the card states (and the master checks each run against).
BOUND = "||e_k|| <= overshoot_bound * decay_bound**k * ||e_0||"


def determined(problem, card_data, analysis: Analysis) -> dict:
    """What the card's problem determines: the sampled plant (with ``W_sampled`` where it declares ``W``),
    ``M = -E (CE)^+``, dhat's matrices (absent unless ``rank(CE) = q``), the step and the schedule; the fixed
    modes and invariant zeros of its analysis, the eigenvalues of the stored ``N``, and the state scaling of an
    LMI design."""
    plant, opts = problem.plant, problem.options
    s, C = plant.sampled(opts.dt), plant.C
    figures = figures_of(analysis, card_data, problem)
    identifiable = not plant.feedthrough and identifiability_condition(C, s.E).holds
    dhat = _dhat(s, C) if identifiable else dict.fromkeys(DHAT)
    mats = {"A_sampled": s.A, "B_sampled": s.B, "E_sampled": s.E, "w_sampled": s.w, "C": C}
    if not plant.feeds_d:                # with F != 0, M is part of the designed gain
        mats["M"] = conditioned(decoupling_gain(C, s.E), condition(C @ s.E))
    mats.update(dhat)
    if plant.feeds_u:
        mats["D"] = plant.D
    if plant.feeds_d:
        mats["F"] = plant.F
    requested = {} if opts.decay == "max" else {"decay_bound": float(opts.decay)}     # a fixed decay is the card's
    if opts.poles is not None:           # the placed poles and the fixed modes decide the decay
        moduli = np.abs(np.concatenate([np.asarray(opts.poles), analysis.data["fixed"]]))
        requested = {"decay_bound": pole_decay(moduli), "poles_placed": complex_list(opts.poles),
                     "poles": spectrum(np.asarray(card_data["matrices"]["N"], dtype=float))}
    noise = {"noise.norm": NORM}                                       # the gains: verify re-checks them
    if dhat["Dy"] is None:
        noise["noise.gain_dhat_y"] = None
    if plant.r:
        mats["W_sampled"] = plant.sampled_noise(opts.dt)
    else:
        noise["noise.gain_w"] = None
    if opts.order == "reduced":
        requested["order"] = "reduced"
    if opts.functional is not None:      # zhat: no M, no dhat; the order the search proves at the decay
        mats.pop("M", None)
        mats.update(dict.fromkeys(DHAT), Lf=opts.functional)
        noise["noise.gain_dhat_y"] = None
        requested.update({"order": analysis.existence.value("functional observer order", "order"),
                          "dims.nf": int(opts.functional.shape[0]), "bound": functional_uio.BOUND})
    return {"dt": opts.dt, "schedule": _schedule(opts), "bound": BOUND, "decay": card_data["decay_bound"], **requested,
            **noise,
            **{f"matrices.{k}": v for k, v in mats.items()}, **figures}


def figures_of(analysis: Analysis, card_data: dict, problem) -> dict:
    """The figures an lti-uio card lists that its analysis and its stored ``N`` determine: the fixed
    modes, the invariant zeros, the eigenvalues of ``N`` and their largest modulus, and the state
    scaling (the card's ``design_method`` says whether its LMIs were solved in scaled coordinates)."""
    plant, opts = problem.plant, problem.options
    A = analysis.data["sampled"].A
    size, n = float(np.linalg.norm(A, 2)), plant.n
    N = np.asarray(card_data["matrices"]["N"], dtype=float)
    full = opts.order == "full" and opts.functional is None
    lmi = str(card_data.get("design_method")).startswith("lmi") and full
    kind = opts.scaling if full else "none"     # the reduced pair and the functional error are solved unscaled
    zeros = functional_uio.full_state_zeros(analysis.existence)     # absent only where rank(CE) < rank(E)
    return {"fixed_modes": computed_values(analysis.data["fixed"], size, n),
            **{k: computed_values(from_pairs(v), size, n) for k, v in zeros.items()},
            "eigenvalues_N": spectrum(N), "spectral_radius_N": spectrum(N, "radius"),
            "scaling": scaling_data(state_scaling(plant.A, opts.scaling) if lmi else np.ones(n), kind)}


def _riccati(PA, C, rho: float) -> Tuned:
    """The Riccati design at decay ``rho``: the gain and its Lyapunov matrix, no solver.

    The point is exact by construction (``rho^2 X - N'XN = rho^2 I``); what certifies it is the
    re-check of :func:`checks` at the stored matrices, as for every design. The LMI's Schur
    form is not evaluated: with the large gains of weakly observable modes its smallest
    eigenvalue drowns in round-off, while the Lyapunov inequality itself does not.
    """
    solve_discrete_lyapunov = blas_module("scipy.linalg").solve_discrete_lyapunov

    try:
        K = decay_gain(PA, C, rho)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InfeasibleError(f"{NAME} Riccati design at decay {rho:.6g}: the Riccati equation of the decay-scaled "
                              f"pair has no usable solution ({str(exc).rstrip('.')})") from None
    N = PA - K @ C
    radius = float(np.abs(np.linalg.eigvals(N)).max())
    if not radius < rho:
        raise InfeasibleError(f"{NAME} Riccati design: N has spectral radius {radius:.6g}, not below the decay "
                              f"{rho:.6g}")
    with warnings.catch_warnings():       # ill-conditioned for large gains: the re-check at the stored matrices judges
        warnings.simplefilter("ignore")
        X = solve_discrete_lyapunov((N / rho).T, np.eye(len(N)))
    X = 0.5 * (X + X.T)
    for check in (positive_check("eig_min(X)", X), lyapunov_check("eig_min(rho^2 X - N'XN)", N, X, rho)):
        if not check.holds:
            eig = np.linalg.eigvalsh(X)
            raise InfeasibleError(f"{NAME} Riccati design at decay {rho:.6g}: {check.explain()}, with cond(X) = "
                                  f"{eig[-1] / max(eig[0], 1e-300):.3g} and gains up to {np.abs(K).max():.3g}; a "
                                  "slower decay needs smaller gains, and units that bring the states to comparable "
                                  "sizes a better conditioned X")
    values = {"X": X, "W": X @ K, "K": K, "t": np.array(float(np.linalg.eigvalsh(X)[-1]))}
    status = "closed form (Riccati gain, discrete Lyapunov equation)"
    return Tuned(rho, LmiSolution(values, {"rho2": rho * rho}, status, {}, True, 0.0, 0.0), None)


def _runtime(s, C, M, X, K, D=None, F=None) -> dict:
    """The card's matrices of a gain ``K`` and its Lyapunov matrix ``X`` (plant coordinates); with the
    feedthrough ``D`` of the known input the observer runs on ``y - D u`` (``G = PB - LD``, ``Xu = MD``), and the
    feedthrough ``F`` of the unknown input is stored for the checks."""
    n = len(X)
    P = np.eye(n) + M @ C
    N = P @ s.A - K @ C
    out = {"N": N, "L": K - N @ M, "G": P @ s.B, "c": P @ s.w, "Xz": np.eye(n), "Xy": -M, "C": C,
           "M": M, "K": K, "P": P, "X": 0.5 * (X + X.T), "A_sampled": s.A, "B_sampled": s.B,
           "E_sampled": s.E, "w_sampled": s.w}
    if D is not None:
        out.update(G=P @ s.B - out["L"] @ D, Xu=M @ D, D=D)
    if F is not None:
        out["F"] = F
    return out


@dataclass(frozen=True)
class Pair:
    """The decoupled pair the design's gain acts on (``N = A - gain C``) and the card's matrices of a gain.

    Attributes
    ----------
    A, C : numpy.ndarray
        ``((I+MC)A, C)`` without feedthrough of the unknown input; ``(A0, O)`` with it
        (:func:`uiofmu.feedthrough.feedthrough_pair`); ``(Ar, Cr)`` of the reduced observer
        (:func:`uiofmu.reduced_order.decoupled`).
    runtime : callable
        ``runtime(X, gain) -> dict``: the card's matrices (:func:`_runtime`, :func:`uiofmu.reduced_order.runtime`).
    """

    A: np.ndarray
    C: np.ndarray
    runtime: object
    #: The card's matrices and checks of the points :meth:`checked` evaluated (by the bytes of ``X``, the gain and
    #: the decay, and the checks): the design's own points only, the pair being made for one design.
    seen: dict = field(default_factory=dict, compare=False, repr=False)
    #: The identities of :func:`checks` that read nothing of the point, kept for the points of one design (its
    #: ``fixed``).
    fixed: dict = field(default_factory=dict, compare=False, repr=False)

    def checked(self, X: np.ndarray, gain: np.ndarray, rho: float, check) -> tuple[dict, list]:
        """The card's matrices of ``(X, gain)`` (:attr:`runtime`) and ``check(matrices, rho)`` at them.

        A point a search re-checked is kept as it was re-checked: the certificate of the design is then the checks
        already made at its matrices, which the same calls on the same bytes of ``X``, the gain and ``rho`` would
        make again to the last bit (the runtime's matrices and every check are deterministic functions of them).
        The matrices returned are a copy: the card may add to them.
        """
        X, gain = np.asarray(X, dtype=float), np.asarray(gain, dtype=float)
        key = (check, float(rho), X.shape, X.tobytes(), gain.shape, gain.tobytes())
        if key not in self.seen:
            matrices = self.runtime(X, gain)
            found = check(matrices, float(rho), self.fixed) if check is checks else check(matrices, float(rho))
            self.seen[key] = (matrices, found)
        matrices, found = self.seen[key]
        return dict(matrices), list(found)

    def lmi_checked(self, values: dict, rho: float, check) -> tuple[dict, list]:
        """:meth:`checked` of an LMI point in the plant's coordinates (``X`` and ``W = X gain``)."""
        return self.checked(values["X"], self.gain(values), rho, check)

    @staticmethod
    def gain(values: dict) -> np.ndarray:
        """``gain = X^-1 W`` of an LMI point."""
        X = values["X"]
        return np.linalg.solve(0.5 * (X + X.T), values["W"])


def decoupled_pair(plant, s) -> Pair:
    """The :class:`Pair` of the plant sampled as ``s`` (its feedthrough included)."""
    C = plant.C
    D = plant.D if plant.feeds_u else None
    if plant.feeds_d:
        fp = feedthrough_pair(s.A, s.E, C, plant.F)

        def runtime(X, Y):
            H, K = fp.gains(Y)
            return _runtime(s, C, -H, X, K, D, plant.F)
        return Pair(fp.A0, fp.O, runtime)
    M = decoupling_gain(C, s.E)
    return Pair((np.eye(len(M)) + M @ C) @ s.A, C, lambda X, K: _runtime(s, C, M, X, K, D))


def _lmi_runtime(s, C, M, values: dict) -> dict:
    """:func:`_runtime` of an LMI point in the plant's coordinates (``X`` and ``W = X K``)."""
    X = values["X"]
    return _runtime(s, C, M, X, np.linalg.solve(0.5 * (X + X.T), values["W"]))


def _tuned(s, pair: Pair, t, largest: float, opts: Options, name: str) -> tuple[Tuned, str, LmiSystem]:
    """The decay and its certificate of the full-order observer (:func:`_decay`), the LMI system solved in the
    coordinates scaled by ``t`` (:class:`uiofmu.scaling.StateScaling`)."""
    scaling = StateScaling(t)
    system, inverse = scaling.apply(PlantLmis(lambda steps, Cs: _lmis(steps[0].A, Cs, opts.gain_cap,
                                                                              plant_identity(t)),
                                              [replace(s, A=pair.A)], pair.C))
    system.figure_spread = identity_spread(t)
    return _decay(system, lambda v: scaling.invert(v, inverse), pair, checks, largest, opts, name)


def _decay(system: LmiSystem, back, pair: Pair, check, largest: float, opts: Options,
           name: str) -> tuple[Tuned, str, LmiSystem]:
    """The decay and its certificate by the requested method (see the module docstring), and the LMI system of
    :func:`_lmis` (its points mapped to the pair's coordinates by ``back``): a point is accepted only where the
    certificate's checks at the runtime's matrices (``check(matrices, rho)``) hold too. The point's ``K`` is the
    gain of ``pair`` (``N = pair.A - K pair.C``); the full-order and the reduced observer share it."""
    PA, C = pair.A, pair.C
    system.certify = lambda v, prm: all(c.holds for c in pair.lmi_checked(back(v), float(np.sqrt(prm["rho2"])),
                                                                           check)[1])
    system.figure = lambda v: overshoot(back(v)["X"])
    if opts.method == "riccati":
        return _riccati(PA, C, float(opts.decay)), "riccati", system
    try:
        tuned = tune(system, "rho2", opts.decay, feasible_end=0.5 * (1.0 + largest), infeasible_end=largest,
                     safe_end=1.0, tol=SEARCH_TOL, label=f"{name}: fastest decay", transform=lambda r: r * r,
                     name="decay", diagnose=opts.method == "lmi")
        values = back(tuned.solution.values)
        values["K"] = pair.gain(values)
        return replace(tuned, solution=replace(tuned.solution, values=values)), "lmi", system
    except InfeasibleError as exc:
        if opts.method == "lmi" or opts.gain_cap is not None:       # the Riccati gain knows no cap
            raise
        rho = 0.5 * (1.0 + largest) if opts.decay == "max" else float(opts.decay)
        try:
            return _riccati(PA, C, rho), "riccati (the LMI found no certificate)", system
        except (InfeasibleError, ValueError, np.linalg.LinAlgError) as fallback:
            raise type(exc)(f"{exc}; the solver-free fallback fails too: {fallback}") from None


#: The room a pole-placed design's certificate takes above the largest modulus ``rho`` of its error dynamics:
#: ``decay_bound = sqrt(rho^2 + POLE_ROOM)`` rounded up to :data:`POLE_DIGITS` significant digits, so that
#: ``decay_bound^2 X - N'XN >= POLE_ROOM I`` (with ``X >= I``) clears the Lyapunov re-check's margin.
POLE_ROOM, POLE_DIGITS = 1e-5, 4
#: Largest condition number of the eigenvector matrix of a pole-placed ``N`` (the overshoot bound) a design accepts:
#: beyond it the poles nearly coincide (with each other or with fixed modes) and ``N`` is nearly defective.
MAX_EIGENVECTOR_CONDITION = 1e6
#: How far (relative to ``max(1, ||N||)``) an eigenvalue of the stored ``N`` may lie from a placed pole.
PLACED_RTOL = 1e-6


def pole_decay(moduli) -> float:
    """The certified decay of an error dynamics whose eigenvalues have these moduli (:data:`POLE_ROOM`)."""
    rho = float(np.max(moduli, initial=0.0))
    return round_up(float(np.sqrt(rho * rho + POLE_ROOM)), POLE_DIGITS)


def _sorted(values) -> np.ndarray:
    """Complex numbers by decreasing modulus, then real part, then imaginary part."""
    values = np.asarray(values, dtype=complex).ravel()
    return values[np.lexsort((values.imag, values.real, -np.abs(values)))]


def _placement(pair: Pair, poles: tuple, fixed_count: int, name: str) -> tuple:
    """``observer.poles``: the gain that places ``poles`` exactly on the observable part of ``pair`` (the fixed
    modes kept), and its certificate (module docstring).

    Returns
    -------
    tuple
        ``(Tuned, design_method, None, record)``, the record holding ``placed`` (the poles asked for),
        ``overshoot_digits`` and the card's ``placement`` entry.
    """
    place_poles = blas_module("scipy.signal").place_poles

    A, C = pair.A, pair.C
    Vo, _ = controllable_split(A.T, C.T)                 # the observable subspace of (A, C)
    if Vo.shape[1] != len(poles):
        raise InfeasibleError(f"{name}: observer.poles lists {len(poles)} pole(s) (conjugates counted), the "
                              f"decoupled pair has {Vo.shape[1]} assignable mode(s)")
    Co = C @ Vo
    U, sv, _ = np.linalg.svd(Co, full_matrices=False)
    r = rank(Co)
    Ur = U[:, :r]
    try:
        placed = place_poles((Vo.T @ A @ Vo).T, (Ur.T @ Co).T, np.asarray(poles))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InfeasibleError(f"{name}: observer.poles cannot be placed on the decoupled pair with {r} independent "
                              f"output direction(s): {str(exc).rstrip('.')} (a pole may repeat at most {r} "
                              "time(s))") from None
    K = Vo @ placed.gain_matrix.T @ Ur.T
    N = A - K @ C
    lam, V = np.linalg.eig(N)
    kappa = float(np.linalg.cond(V))
    if not kappa <= MAX_EIGENVECTOR_CONDITION:
        raise InfeasibleError(f"{name}: the placed error dynamics has an eigenvector matrix of condition number "
                              f"{kappa:.3g} > {MAX_EIGENVECTOR_CONDITION:g} (poles that nearly coincide with each "
                              f"other or with the fixed modes make N nearly defective): spread the poles")
    X = np.linalg.inv((V @ V.conj().T).real)
    X = 0.5 * (X + X.T)
    X = X / float(np.linalg.eigvalsh(X)[0])
    rho = pole_decay(np.abs(lam))
    values = {"X": X, "W": X @ K, "K": K, "t": np.array(float(np.linalg.eigvalsh(X)[-1]))}
    status = "closed form (pole placement, eigenvector Lyapunov matrix)"
    record = {"algorithm": f"scipy.signal.place_poles ({placed.rtol:.3g} rtol reached)"
              if np.isfinite(placed.rtol) else "scipy.signal.place_poles",
              "output_directions": r, "fixed_modes": fixed_count, "eigenvector_condition": kappa,
              "bound": "||e_k|| <= cond(V) max|eig(N)|^k ||e_0||, certified at decay_bound with X = (V V^H)^-1"}
    sol = LmiSolution(values, {"rho2": rho * rho}, status, {}, True, 0.0, 0.0)
    return (Tuned(rho, sol, None), "pole placement", None,
            {"placed": complex_list(poles), "overshoot_digits": FIGURE_DIGITS if r == 1 else UNDETERMINED,
             "record": record})


def pole_checks(card_data: dict) -> list:
    """Each pole a card says it placed (``poles_placed``) is an eigenvalue of its stored ``N`` (none without)."""
    placed = card_data.get("poles_placed")
    if placed is None:
        return []
    N = np.asarray(card_data["matrices"]["N"], dtype=float)
    eig = np.linalg.eigvals(N)
    tol = PLACED_RTOL * max(1.0, float(np.linalg.norm(N, 2)))
    return [Check(f"placed pole {p.real:.6g}{p.imag:+.6g}j: distance to the nearest eigenvalue of N",
                  float(np.min(np.abs(eig - p))), tol) for p in from_pairs(placed)]


def design(problem, analysis: Analysis) -> DesignResult:
    """Design the classical UIO: its gain, certificate and runtime matrices."""
    s, fixed = analysis.data["sampled"], analysis.data["fixed"]
    plant, opts = problem.plant, problem.options
    if opts.functional is not None:
        return functional_uio.card_design(problem, analysis, NAME, _schedule(opts), noise_section)
    if plant.feeds_d and (opts.noise == "min" or opts.noise_gain is not None):    # options made in code, unparsed
        raise ProblemError(NO_NOISE_DESIGN_WITH_F)
    if opts.order == "reduced":
        return _reduced(problem, analysis)
    C = plant.C
    pair = decoupled_pair(plant, s)
    t = state_scaling(plant.A, opts.scaling)
    largest = float(np.abs(fixed).max()) if fixed.size else 0.0
    placed = None
    if opts.poles is not None:
        tuned, method, system, placed = _placement(pair, opts.poles, len(fixed), problem.name)
    else:
        tuned, method, system = _tuned(s, pair, t, largest, opts, problem.name)
    rho, sol, spread = tuned.value, tuned.solution, 1.0 if system is None else system.figure_spread
    searched = tuned.search.to_data() if tuned.search else None
    noise_design = None
    if opts.noise_gain is not None:
        rho, sol, system, method, noise_design = _fastest_within(s, C, decoupling_gain(C, s.E), t, rho, sol, system,
                                                                 method, opts, problem.name)
    elif opts.noise == "min":
        rho, sol, system, method, noise_design = _noise_design(s, C, decoupling_gain(C, s.E), t, rho, sol, system,
                                                               method, opts, problem.name)
    matrices, found = pair.checked(sol.values["X"], sol.values["K"], rho, checks)
    cert = certificate(sol, found, f"{NAME} design of {problem.name}", solver=_solver(method))
    if placed is not None:
        digits = placed["overshoot_digits"]
    else:
        digits = UNDETERMINED if method == NOISE_METHOD else figure_digits(sol, spread)
    extra = {**({} if noise_design is None else {"noise_design": noise_design}),
             **({} if placed is None else {"poles": complex_list(_sorted(np.linalg.eigvals(matrices["N"]))),
                                           "poles_placed": placed["placed"],
                                           "placement": placed["record"]})}
    figures = {"decay": rho, "overshoot_bound": overshoot(matrices["X"]), "overshoot_digits": digits,
               "search": searched, "design_method": method,
               "scaling": scaling_data(t if method.startswith("lmi") else np.ones(plant.n), opts.scaling)}
    return _result(problem, analysis, plant.n, matrices, cert, system, figures, extra=extra)


def _reduced(problem, analysis: Analysis) -> DesignResult:
    """``observer.order = "reduced"``: the gain of the reduced pair (:func:`uiofmu.reduced_order.decoupled`) by
    :func:`_decay` (the decay LMI unscaled: the pair's coordinates are orthonormal ones of the plant's), its
    certificate by :func:`uiofmu.reduced_order.checks` and bound by :func:`uiofmu.reduced_order.bound`, and the
    rest of the card as the full-order observer's."""
    s, fixed = analysis.data["sampled"], analysis.data["fixed"]
    plant, opts = problem.plant, problem.options
    pair = Pair(*reduced_order.decoupled(problem, s))
    largest = float(np.abs(fixed).max()) if fixed.size else 0.0
    tuned, method, system = _decay(_lmis(pair.A, pair.C, opts.gain_cap), dict, pair, reduced_order.checks, largest,
                                   opts, problem.name)
    rho, sol = tuned.value, tuned.solution
    matrices, found = pair.checked(sol.values["X"], sol.values["K"], rho, reduced_order.checks)
    cert = certificate(sol, found, f"{NAME} reduced-order design of {problem.name}", solver=_solver(method))
    figures = {"decay": rho, "overshoot_bound": reduced_order.bound(matrices),
               "overshoot_digits": UNDETERMINED,       # ||Zx|| reads the gain, which the LMI's optimum does not fix
               "search": tuned.search.to_data() if tuned.search else None, "design_method": method,
               "scaling": scaling_data(np.ones(plant.n), "none")}
    return _result(problem, analysis, plant.n - plant.p, matrices, cert, system, figures, head={"order": "reduced"})


def _solver(method: str) -> str:
    """The card's ``certificate.solver`` of a design method: CLARABEL for the LMIs, none for a closed form."""
    return "CLARABEL" if method.startswith("lmi") else "none"


def _result(problem, analysis: Analysis, nz: int, matrices: dict, cert: dict, system, figures: dict,
            head: dict | None = None, extra: dict | None = None) -> DesignResult:
    """The design of a certified gain (of either order) as the card holds it.

    ``matrices`` gain dhat's (``rank(CE) = q``, no feedthrough) and ``W_sampled`` (``[plant] W``); the results are
    ``head``, the decay (also ``decay_bound``), the overshoot bound and its digits of ``figures``, the bound, the
    fixed modes and invariant zeros, ``N``'s spectrum, the search, design method and scaling of ``figures``, the
    noise section (:func:`noise_section`), then ``extra``.
    """
    existence, s, fixed = analysis.existence, analysis.data["sampled"], analysis.data["fixed"]
    plant, opts = problem.plant, problem.options
    if not plant.feedthrough and existence.holds("rank(CE) = q"):
        matrices.update({k: v[0] for k, v in dhat_matrices(plant.C, s.A[None], s.B[None], s.E[None],
                                                            s.w[None]).items()})
    if plant.r:
        matrices["W_sampled"] = plant.sampled_noise(opts.dt)
    eigN = np.linalg.eigvals(matrices["N"])
    results = {
        **(head or {}),
        "decay": figures["decay"],
        "decay_bound": figures["decay"],
        "overshoot_bound": figures["overshoot_bound"],
        "overshoot_digits": figures["overshoot_digits"],
        "bound": BOUND,
        "fixed_modes": complex_list(fixed),
        "invariant_zeros": existence.value("stable invariant zeros", "zeros"),
        "eigenvalues_N": complex_list(eigN),
        "spectral_radius_N": float(np.abs(eigN).max()),
        "search": figures["search"],
        "design_method": figures["design_method"],
        "scaling": figures["scaling"],
        "noise": noise_section(matrices),
        **(extra or {}),
    }
    return DesignResult(nz, opts.dt, _schedule(opts), matrices, cert, results, system, opts.xhat0)
