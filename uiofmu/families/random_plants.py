"""Random problems for the design-robustness campaign (not from the papers).

Every problem is drawn from a seed alone, the same seed giving the same document on every
machine (numpy's ``default_rng`` seeded by ``[seed, family]``; no global state is touched).
:func:`random_problem` returns the problem document (what
:func:`uiofmu.problem.problem_from_data` takes), :func:`campaign` yields a family's problems,
:func:`draw` returns the document with what the generator knows about it (the plant class,
the zeros it built in, whether an observer should exist, the fixed values to try).

How a plant is built
--------------------
In coordinates ``x = (xi, eta)`` with ``y = xi`` (p states measured) and the unknown input
acting on ``xi`` only (``E = [E1; 0]``, ``E1`` of full column rank, so ``rank(CE) = rank(E)
= q``), the zero dynamics are the largest ``A22``-invariant subspace of ``ker(Pi A12)``
(``Pi`` the projector onto ``range(E1)``'s complement). It is built in: ``A22 = [[Z, *],
[0, O]]`` with the columns of ``A12`` for ``Z`` inside ``range(E1)`` and ``(O, Pi A12_O)``
observable, so the invariant zeros of ``(A, E, C)`` are exactly ``eig(Z)`` (all of
``eig(A22)`` when ``p = q``), and they are the fixed modes of ``((I + MC) A, C)`` that no
observer gain moves. The plant's own eigenvalues are then placed by output injection
``A - F C`` (:func:`scipy.signal.place_poles` on the dual pair), which leaves the invariant
zeros where they are; the matrix is balanced (a diagonal similarity, which keeps poles and
zeros) and hidden by a random similarity, a mixing of the outputs and scalings of the
outputs, of the unknown inputs and (continuous plants) of time. The zeros of the result are
recomputed and compared with the ones built in; a draw whose zeros moved is drawn again.

Plant classes (drawn per seed)
------------------------------
``well-conditioned``
    Moderate poles and zeros, a near-orthogonal similarity, outputs and inputs of unit size.
``badly-scaled``
    Rows of C and columns of E scaled by factors from 1e-3 to 1e3, states by 10^±1.5.
``stiff``
    Real poles (and zeros) spread over three to five decades.
``lightly-damped``
    One or two pole pairs with damping 1e-3 to 1e-2 (and in half the draws a lightly damped
    zero pair).
``near-limit-zeros``
    One invariant zero (real or a pair) whose margin to the stability limit is 1e-6 to 1e-2:
    ``|z| = exp(-eps)`` for a discrete plant, ``Re z = -eps / h`` for a continuous one, so that
    sampled at the base step h its modulus is about ``1 - eps`` as well (a continuous plant of
    this class is square, p = q: a non-square one generically loses its zeros when sampled; the
    sampled zeros of a square one are close to ``exp(z h)``, not equal, so the check decides).
``integrators``
    One pole (two when p >= 2, in some draws) at 0 (continuous) or 1 (discrete).
``rank-deficient`` (a minority, on purpose)
    ``E`` has a direction that ``C`` does not see: ``rank(CE) < rank(E)`` for a discrete plant
    (no observer exists); a continuous plant sampled at ``h`` usually regains the rank (the
    check decides).
``unstable-zero`` (a minority, on purpose)
    One invariant zero outside the stability region: no observer exists.

Sizes: n = 2..6 states, p = 1..3 outputs (at most n), q = 1..2 unknown inputs (at most p except
in some rank-deficient draws), m = 0..2 known inputs. Scales: continuous time by a factor
10^-3..10^3, the unknown input's unit by 10^-3..10^3.

Families
--------
``lti-uio``
    Discrete plants (60 %) and continuous ones with ``observer.dt`` (the base step);
    ``decay = "max"``.
``ltv-auid``
    Discrete plants; ``alpha`` in [0.8, 0.995] and ``eta`` a fraction of the zero limit
    ``1 - max|z|^2`` (at most 0.3), as in seed 000; ``mu = "max"``.
``sampled-data``
    Continuous plants; 2..6 intervals, distinct multiples (1..8) of a base step of 0.03 to 0.3
    of the plant's time unit; ``alpha = "max"``.

Fixed values below the max (the feasible side)
----------------------------------------------
A ``"max"`` design certifies the best value; every value on the *feasible side* of it is
certifiable too (the LMIs only get easier), so a design at such a value must succeed.
:func:`fixed_values` picks them from the fractions ``f`` of :attr:`RandomProblem.fractions`
(one in [0.9, 0.99], one in [0.4, 0.6], one in [0.05, 0.2]; ``f`` near 1 is near the max):

* ``lti-uio``: the feasible side is **above** the max decay (slower contraction per step):
  ``decay = max + (1 - f) (1 - max)``, in (max, 1).
* ``sampled-data``: **below** the max alpha (slower decay ``sqrt(1 - alpha)``):
  ``alpha = f * max``, in (0, max).
* ``ltv-auid``: **below** the max mu (a smaller transient boost ``tau_1 = eta (1 + mu)``):
  ``mu = f * max``, in (0, max).
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..runtime.registry import FAMILIES
from ..threads import blas_module

#: The families the campaign covers, with the code that decorrelates their streams (the registry's
#: :attr:`~uiofmu.runtime.registry.Entry.random_code`).
FAMILY_CODES = {e.name: e.random_code for e in FAMILIES.values() if e.random_code is not None}

#: The key of ``[observer]`` that ``"max"`` searches, per family.
SEARCHED = {"lti-uio": "decay", "ltv-auid": "mu", "sampled-data": "alpha"}

#: Plant classes and their probabilities.
CLASSES = {"well-conditioned": 0.18, "badly-scaled": 0.15, "stiff": 0.15, "lightly-damped": 0.15,
           "near-limit-zeros": 0.15, "integrators": 0.12, "rank-deficient": 0.05, "unstable-zero": 0.05}

#: Classes built so that no observer exists (for a discrete plant; see the module docstring).
NO_OBSERVER_CLASSES = ("rank-deficient", "unstable-zero")

#: The knobs :func:`draw` accepts.
KNOBS = ("plant_class", "n", "p", "q", "m", "time", "intervals", "n_max", "intervals_max")

#: Where the fractions of the fixed values are drawn (near the max, half way, far).
FRACTION_RANGES = ((0.9, 0.99), (0.4, 0.6), (0.05, 0.2))

#: Largest plant eigenvalue modulus (normalised time) kept for a discrete plant's fast modes.
_DISCRETE_FASTEST = 20.0


@dataclass(frozen=True)
class RandomProblem:
    """A drawn problem and what the generator knows about it.

    Attributes
    ----------
    doc : dict
        The problem document (``name``, ``[plant]``, ``[observer]`` with the searched key set to
        ``"max"``).
    family : str
    seed : int
    plant_class : str
        One of :data:`CLASSES`.
    time : {"discrete", "continuous"}
    n, p, q, m : int
        States, outputs, unknown inputs, known inputs.
    expect_exists : bool or None
        Whether an observer exists by construction (None: the check decides, e.g. a continuous
        plant whose sampled ``CE`` regains its rank).
    zeros : tuple of complex
        The invariant zeros built in, in the plant's own time domain.
    margin : float or None
        The built-in margin ``eps`` of a near-limit zero (sampled at the base step).
    base_step : float or None
        ``observer.dt`` (lti-uio on a continuous plant) or the base of the intervals.
    fractions : tuple of float
        Where the fixed values go between the max and the end of the feasible side
        (see :func:`fixed_values`).
    attempts : int
        Draws needed until the zeros came out where they were built.
    """

    doc: dict
    family: str
    seed: int
    plant_class: str
    time: str
    n: int
    p: int
    q: int
    m: int
    expect_exists: bool | None
    zeros: tuple = field(default_factory=tuple)
    margin: float | None = None
    base_step: float | None = None
    fractions: tuple = field(default_factory=tuple)
    attempts: int = 1

    @property
    def name(self) -> str:
        """The document's name."""
        return self.doc["name"]


# -- spectra ---------------------------------------------------------------------------------

def _moderate(rng, k: int, complex_share: float = 0.4) -> list:
    """Eigenvalue specs filling dimension ``k``: real ``-U(0.1, 2)`` or pairs ``-zeta w ± i w``
    (zeta in [0.1, 0.9], w in [0.3, 2]), in normalised continuous time. A pair is one complex
    entry with positive imaginary part."""
    out = []
    while k > 0:
        if k >= 2 and rng.random() < complex_share:
            zeta, w = rng.uniform(0.1, 0.9), rng.uniform(0.3, 2.0)
            out.append(complex(-zeta * w, w * math.sqrt(1 - zeta * zeta)))
            k -= 2
        else:
            out.append(complex(-rng.uniform(0.1, 2.0), 0.0))
            k -= 1
    return out


def _spread(rng, k: int, lo: float, span: float) -> list:
    """``k`` real values ``-10^t`` with t spread over ``[lo, lo + span]`` (stiff spectra)."""
    if k == 0:
        return []
    t = np.sort(lo + span * (np.arange(k) + rng.uniform(0.2, 0.8, size=k)) / k)
    t[0], t[-1] = (lo, lo + span) if k > 1 else (t[0], t[-1])
    return [complex(-(10.0 ** v), 0.0) for v in t]


def _light(rng) -> complex:
    """A lightly damped pair: damping 1e-3..1e-2, frequency 0.3..2 (normalised)."""
    zeta, w = 10.0 ** rng.uniform(-3, -2), rng.uniform(0.3, 2.0)
    return complex(-zeta * w, w * math.sqrt(1 - zeta * zeta))


def _dimension(specs) -> int:
    return sum(2 if s.imag else 1 for s in specs)


def _to_discrete(specs, rng, flip: float = 0.15, keep=()) -> list:
    """Map normalised continuous eigenvalues to one step: ``exp(lambda)``; some real ones are
    mirrored to negative values (indices in ``keep`` are not)."""
    out = []
    for i, s in enumerate(specs):
        mag = min(abs(s), _DISCRETE_FASTEST) / max(abs(s), 1e-300) if abs(s) else 1.0
        v = complex(np.exp(complex(s) * mag))
        if not s.imag:
            v = complex(v.real, 0.0)
            if i not in keep and rng.random() < flip:
                v = -v
        out.append(v)
    return out


def _expand(specs) -> np.ndarray:
    """Specs to the full list of eigenvalues (pairs expanded)."""
    out = []
    for s in specs:
        out += [s, s.conjugate()] if s.imag else [complex(s.real, 0.0)]
    return np.array(out, dtype=complex)


def _real_block(specs) -> np.ndarray:
    """A real block-diagonal matrix with the eigenvalues ``specs``."""
    k = _dimension(specs)
    M = np.zeros((k, k))
    i = 0
    for s in specs:
        if s.imag:
            M[i:i + 2, i:i + 2] = [[s.real, s.imag], [-s.imag, s.real]]
            i += 2
        else:
            M[i, i] = s.real
            i += 1
    return M


def _orthogonal(rng, k: int) -> np.ndarray:
    """A random orthogonal matrix (Haar)."""
    if k == 0:
        return np.zeros((0, 0))
    Q, R = np.linalg.qr(rng.normal(size=(k, k)))
    return Q * np.sign(np.diag(R))


def _conditioned(rng, k: int, spread: float) -> np.ndarray:
    """``Q1 diag(10^U(-spread, spread)) Q2``: a random matrix of condition up to 10^(2 spread)."""
    return _orthogonal(rng, k) @ np.diag(10.0 ** rng.uniform(-spread, spread, size=k)) @ _orthogonal(rng, k)


# -- the construction ------------------------------------------------------------------------

def _normal_form(rng, n, p, q, zero_specs, nz, pole_values, rank_deficient):
    """(A, E, C) in the coordinates (xi, eta) with the zeros built in and the poles placed."""
    place_poles = blas_module("scipy.signal").place_poles

    E1 = _orthogonal(rng, p)[:, :q] if q <= p else rng.normal(size=(p, q))
    no = n - p - nz
    Z = _real_block(zero_specs)
    if nz:
        V = _conditioned(rng, nz, 0.3)
        Z = V @ Z @ np.linalg.inv(V)
    O = rng.normal(size=(no, no))
    A22 = np.zeros((n - p, n - p))
    A22[:nz, :nz] = Z
    A22[:nz, nz:] = rng.normal(size=(nz, no))
    A22[nz:, nz:] = O
    A12 = np.hstack([E1 @ rng.normal(size=(E1.shape[1], nz)), rng.normal(size=(p, no))])
    A = np.zeros((n, n))
    A[:p, :p] = rng.normal(size=(p, p))
    A[:p, p:] = A12
    A[p:, :p] = rng.normal(size=(n - p, p))
    A[p:, p:] = A22
    C = np.hstack([np.eye(p), np.zeros((p, n - p))])
    E = np.vstack([E1, np.zeros((n - p, q))])
    if rank_deficient:
        # a direction of E that C does not see: the last column enters eta only
        E[:p, -1] = 0.0 if q == 1 else E[:p, 0] * rng.normal()
        E[p:, -1] = rng.normal(size=n - p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                 # YT's "convergence not reached" is harmless
        gain = place_poles(A.T, C.T, pole_values, method="YT").gain_matrix
    return A - gain.T @ C, E, C


def _balanced(A, E, C):
    """Diagonal similarity that balances A (keeps poles and zeros)."""
    matrix_balance = blas_module("scipy.linalg").matrix_balance

    _, (s, _) = matrix_balance(A, permute=False, separate=True)
    return A * (1.0 / s)[:, None] * s[None, :], E / s[:, None], C * s[None, :]


def _zeros_match(A, E, C, built, discrete) -> bool:
    """Whether the invariant zeros of (A, E, C) are the built-in ones: each within 1e-6
    (relative) and within 1 % of its distance to the stability limit."""
    from ..structure import invariant_zeros

    z = invariant_zeros(A, E, C)
    if len(z) != len(built):
        return False
    left = list(z)
    for w in built:
        i = int(np.argmin([abs(v - w) for v in left]))
        distance = abs(1.0 - abs(w)) if discrete else abs(w.real)
        tol = min(1e-6 * max(1.0, abs(w)), 0.01 * distance) if distance > 0 else 1e-6 * max(1.0, abs(w))
        if abs(left[i] - w) > tol:
            return False
        left.pop(i)
    return True


def _sizes(rng, klass, knobs, time):
    n = int(knobs.get("n", min(rng.integers(2, 7), knobs.get("n_max", 6))))
    needs_eta = klass in ("near-limit-zeros", "unstable-zero", "rank-deficient")
    top = min(3, n - 1 if needs_eta else n)
    p = int(knobs.get("p", rng.integers(1, max(top, 1) + 1)))
    if klass == "rank-deficient" and p == 1 and rng.random() < 0.3:
        q_default = 2                                   # more unknown inputs than outputs
    else:
        q_default = rng.integers(1, min(2, p) + 1)
    if klass in ("near-limit-zeros", "unstable-zero") and time == "continuous" and "p" not in knobs:
        # square: a non-square plant generically loses its zeros when sampled
        p = min(p, 2)
        q_default = p
    q = int(knobs.get("q", q_default))
    m = int(knobs.get("m", rng.integers(0, 3)))
    if not (2 <= n and 1 <= p <= n and 1 <= q and 0 <= m):
        raise ValueError(f"random_problem: sizes n = {n}, p = {p}, q = {q}, m = {m} out of range")
    if needs_eta and n - p < 1:
        raise ValueError(f"random_problem: class {klass!r} needs n > p, found n = {n}, p = {p}")
    return n, p, q, m


def _zero_count(rng, klass, n, p, q):
    if q >= p:
        return n - p
    lo = 1 if klass in ("near-limit-zeros", "unstable-zero") else 0
    if n - p < lo:
        return 0
    if lo == 0 and rng.random() < 0.2:
        return 0
    return int(rng.integers(max(lo, 1), n - p + 1))


def _spectra(rng, klass, n, p, nz, kappa, discrete):
    """Pole and zero specs (normalised continuous time), the near-limit margin, and the indices
    of the zero specs that must not be mirrored."""
    margin = None
    keep = ()
    if klass == "stiff":
        lo, span = rng.uniform(-2.5, -1.0), rng.uniform(3.0, 5.0)
        poles = _spread(rng, n, lo, span)
        zeros = _spread(rng, nz, lo + 0.5, span - 0.5) if nz else []
    elif klass == "lightly-damped":
        pairs = min(n // 2, 1 + int(rng.random() < 0.4))
        poles = [_light(rng) for _ in range(pairs)] + _moderate(rng, n - 2 * pairs)
        if nz >= 2 and rng.random() < 0.5:
            zeros = [_light(rng)] + _moderate(rng, nz - 2)
        else:
            zeros = _moderate(rng, nz)
    elif klass == "integrators":
        k = 2 if p >= 2 and n >= 3 and rng.random() < 0.35 else 1
        poles = [complex(0.0, 0.0)] * k + _moderate(rng, n - k)
        zeros = _moderate(rng, nz)
    else:
        poles = _moderate(rng, n)
        zeros = _moderate(rng, nz)
        if klass in ("well-conditioned", "badly-scaled") and rng.random() < 0.25:
            i = next((j for j, s in enumerate(poles) if not s.imag), None)
            if i is not None:
                poles[i] = complex(rng.uniform(0.002, 0.02), 0.0)      # a mildly unstable plant
    if klass == "near-limit-zeros":
        eps = 10.0 ** rng.uniform(-6, -2)
        margin = eps
        rate = eps if discrete else eps / kappa
        if nz >= 2 and rng.random() < 0.4:
            w = rng.uniform(0.3, 2.0)
            zeros = [complex(-rate, w)] + _moderate(rng, nz - 2)
        else:
            zeros = [complex(-rate, 0.0)] + _moderate(rng, nz - 1)
        keep = (0,)
    elif klass == "unstable-zero":
        zeros = [complex(rng.uniform(0.05, 1.0), 0.0)] + _moderate(rng, nz - 1)
        keep = (0,)
    return poles, zeros, margin, keep


def _distinct(values: np.ndarray, rng) -> np.ndarray:
    """Nudge coinciding real poles apart (place_poles takes a multiplicity up to p only for
    intended repeated values such as integrators)."""
    vals = values.copy()
    for i in range(len(vals)):
        for j in range(i):
            if vals[i] != 0 and vals[i] != 1 and abs(vals[i] - vals[j]) < 1e-6 * max(1.0, abs(vals[i])):
                vals[i] = vals[i] * (1 + 1e-3 * rng.uniform(1, 2))
    return vals


def _draw_plant(rng, klass, n, p, q, m, time, kappa):
    discrete = time == "discrete"
    nz = _zero_count(rng, klass, n, p, q)
    poles, zeros, margin, keep = _spectra(rng, klass, n, p, nz, kappa, discrete)
    if discrete:
        pole_values = _expand(_to_discrete(poles, rng))
        zero_specs = _to_discrete(zeros, rng, keep=keep)
    else:
        pole_values = _expand(poles)
        zero_specs = zeros
    pole_values = _distinct(pole_values, rng)
    rank_deficient = klass == "rank-deficient"
    A, E, C = _normal_form(rng, n, p, q, zero_specs, nz, pole_values, rank_deficient)
    A, E, C = _balanced(A, E, C)
    spread = {"well-conditioned": 0.3, "badly-scaled": 1.5}.get(klass, 0.6)
    T = _conditioned(rng, n, spread)
    Ti = np.linalg.inv(T)
    A, E, C = T @ A @ Ti, T @ E, C @ Ti
    out_spread = 3.0 if klass == "badly-scaled" else 0.3
    C = np.diag(10.0 ** rng.uniform(-out_spread, out_spread, size=p)) @ _orthogonal(rng, p) @ C
    E = E @ np.diag(10.0 ** rng.uniform(-out_spread, out_spread, size=q))
    B = T @ rng.normal(size=(n, m)) if m else np.zeros((n, 0))
    return A, B, E, C, _expand(zero_specs) if zero_specs else np.zeros(0, dtype=complex), margin


def _name(family, seed, klass, time, n, p, q, m, log_t, log_d, extra="") -> str:
    t = "d" if time == "discrete" else "c"
    scale = f"-ts{log_t:+.0f}" if log_t is not None else ""
    return f"{family}-seed{seed}-{klass}-{t}-n{n}p{p}q{q}m{m}{scale}-du{log_d:+.0f}{extra}"


def draw(family: str, seed: int, **knobs) -> RandomProblem:
    """Draw one random problem of ``family`` from ``seed``.

    Parameters
    ----------
    family : {"lti-uio", "ltv-auid", "sampled-data"}
    seed : int
        Any non-negative integer; with the family it fixes everything.
    **knobs
        Overrides of the random choices: ``plant_class`` (one of :data:`CLASSES`), ``n``, ``p``,
        ``q``, ``m``, ``time`` (lti-uio only: ``"discrete"`` or ``"continuous"``), ``intervals``
        (sampled-data: their count, 2..6); caps that keep the draw otherwise the same:
        ``n_max`` (states), ``intervals_max`` (sampled-data intervals).

    Returns
    -------
    RandomProblem

    Raises
    ------
    ValueError
        For an unknown family or knob, or sizes out of range.
    """
    _check_request(family, seed, knobs)
    rng = np.random.default_rng([int(seed), FAMILY_CODES[family]])
    klass, time = _class_and_time(rng, family, knobs)
    n, p, q, m = _sizes(rng, klass, knobs, time)
    # the base step in normalised time (continuous plants), time scale and unit of d
    kappa = 10.0 ** (rng.uniform(-1.5, -0.5) if family == "sampled-data" else rng.uniform(-1.5, 0.0))
    log_t = float(rng.uniform(-3, 3)) if time == "continuous" else None
    log_d = float(rng.uniform(-3, 3))
    discrete = time == "discrete"
    A, B, E, C, zeros, margin, attempts = _plant_attempts(rng, klass, n, p, q, m, time, kappa)
    scale_t = 10.0 ** log_t if log_t is not None else 1.0
    A = A * scale_t
    E = E * (10.0 ** log_d) * scale_t
    B = B * scale_t
    zeros = zeros * scale_t
    base = kappa / scale_t if not discrete else None
    observer, extra = _observer(rng, family, knobs, zeros, discrete, base)
    fractions = tuple(float(rng.uniform(lo, hi)) for lo, hi in FRACTION_RANGES)
    plant = {"time": time, "A": A.tolist(), "E": E.tolist(), "C": C.tolist()}
    if m:
        plant["B"] = B.tolist()
    if discrete:
        plant["dt"] = 0.1
    name = _name(family, int(seed), klass, time, n, p, q, m, log_t, log_d, extra)
    doc = {"name": name, "plant": plant, "observer": observer}
    if klass in NO_OBSERVER_CLASSES:
        expect = False if (discrete or klass == "unstable-zero") else None
    else:
        expect = True
    return RandomProblem(doc=doc, family=family, seed=int(seed), plant_class=klass, time=time, n=n, p=p, q=q,
                         m=m, expect_exists=expect, zeros=tuple(complex(z) for z in zeros), margin=margin,
                         base_step=base, fractions=fractions, attempts=attempts)


def _check_request(family: str, seed: int, knobs: dict) -> None:
    """Refuse an unknown family or knob and a negative seed (:func:`draw`)."""
    if family not in FAMILY_CODES:
        raise ValueError(f"random_problem: unknown family {family!r} (families: {', '.join(FAMILY_CODES)})")
    unknown = sorted(set(knobs) - set(KNOBS))
    if unknown:
        raise ValueError(f"random_problem: unknown knob {unknown[0]!r} (knobs: {', '.join(KNOBS)})")
    if int(seed) < 0:
        raise ValueError(f"random_problem: seed must be >= 0, found {seed}")


def _class_and_time(rng, family: str, knobs: dict) -> tuple:
    """The plant class and time (``"discrete"`` or ``"continuous"``) of a draw: drawn, or as the knobs
    give them (the draws are made either way, so a knob changes nothing else)."""
    names, weights = list(CLASSES), np.array(list(CLASSES.values()))
    klass = str(rng.choice(names, p=weights / weights.sum()))
    klass = knobs.get("plant_class") or klass
    if klass not in CLASSES:
        raise ValueError(f"random_problem: unknown plant_class {klass!r} (classes: {', '.join(CLASSES)})")
    if family == "lti-uio":
        time = "discrete" if rng.random() < 0.6 else "continuous"
        time = knobs.get("time") or time
    else:
        if knobs.get("time") not in (None, "discrete" if family == "ltv-auid" else "continuous"):
            raise ValueError(f"random_problem: {family} problems here are "
                             f"{'discrete' if family == 'ltv-auid' else 'continuous'}")
        time = "discrete" if family == "ltv-auid" else "continuous"
    if time not in ("discrete", "continuous"):
        raise ValueError(f"random_problem: time must be 'discrete' or 'continuous', found {time!r}")
    return klass, time


def _plant_attempts(rng, klass, n, p, q, m, time, kappa) -> tuple:
    """``(A, B, E, C, zeros, margin, attempts)``: :func:`_draw_plant` drawn again (at most 20 times) until
    its invariant zeros are the ones intended (a rank-deficient plant's are not checked)."""
    discrete = time == "discrete"
    attempts = 0
    while True:
        attempts += 1
        try:
            A, B, E, C, zeros, margin = _draw_plant(rng, klass, n, p, q, m, time, kappa)
        except (ValueError, np.linalg.LinAlgError):
            if attempts >= 20:
                raise
            continue
        if klass == "rank-deficient" or _zeros_match(A, E, C, zeros, discrete) or attempts >= 20:
            return A, B, E, C, zeros, margin, attempts


def _observer(rng, family: str, knobs: dict, zeros, discrete: bool, base) -> tuple:
    """The ``[observer]`` table of a draw and the suffix of its name (``-N3`` for 3 sampled-data intervals)."""
    observer: dict = {"family": family}
    extra = ""
    if family == "lti-uio":
        if not discrete:
            observer["dt"] = float(base)
        observer["decay"] = "max"
    elif family == "ltv-auid":
        zmax = float(np.abs(zeros).max()) if zeros.size else 0.0
        room = 1.0 - zmax * zmax
        eta = min(0.3, 10.0 ** rng.uniform(-1.5, -0.2) * room) if room > 0 else 10.0 ** rng.uniform(-3, -1)
        observer.update({"alpha": float(rng.uniform(0.8, 0.995)), "eta": float(eta), "mu": "max"})
    else:
        count = int(knobs.get("intervals", min(rng.integers(2, 7), knobs.get("intervals_max", 6))))
        if not 2 <= count <= 6:
            raise ValueError(f"random_problem: intervals must be 2..6, found {count}")
        multiples = (np.arange(1, count + 1) if rng.random() < 0.5 else
                     np.sort(rng.choice(np.arange(1, 9), size=count, replace=False)))
        observer["intervals"] = [float(base * k) for k in multiples]
        observer["alpha"] = "max"
        extra = f"-N{count}"
    return observer, extra


def random_problem(family: str, seed: int, **knobs) -> dict:
    """One random problem document (see :func:`draw` for the parameters).

    Returns
    -------
    dict
        ``{"name", "plant", "observer"}`` as :func:`uiofmu.problem.problem_from_data` takes it;
        the name carries the family, the seed and the plant's character, e.g.
        ``sampled-data-seed7-stiff-c-n4p2q1m0-ts+2-du-1-N3`` (``c``/``d``: continuous or
        discrete; ``ts``: log10 of the time scale; ``du``: log10 of the unknown input's unit;
        ``N``: number of intervals).

    Examples
    --------
    >>> from uiofmu.problem import problem_from_data
    >>> doc = random_problem("lti-uio", 3)
    >>> problem_from_data(doc).family
    'lti-uio'
    """
    return draw(family, seed, **knobs).doc


def campaign_seeds(count: int, seed: int = 0) -> list[int]:
    """The problem seeds of a campaign: ``seed * 1_000_000 + i`` for i < count (readable, and a
    shorter campaign is the start of a longer one)."""
    if not 0 <= count <= 1_000_000:
        raise ValueError(f"campaign: count must be 0..1000000, found {count}")
    return [int(seed) * 1_000_000 + i for i in range(count)]


def campaign_draws(family: str, count: int, seed: int = 0, **knobs):
    """Yield ``count`` :class:`RandomProblem` of ``family`` (see :func:`campaign_seeds`; knobs as
    for :func:`draw`)."""
    for s in campaign_seeds(count, seed):
        yield draw(family, s, **knobs)


def campaign(family: str, count: int, seed: int = 0, **knobs):
    """Yield ``count`` problem documents of ``family``, seeded (see :func:`campaign_seeds`).

    Parameters
    ----------
    family : str
    count : int
    seed : int
        The campaign's seed.
    **knobs
        As for :func:`draw` (e.g. ``n_max = 4`` for a quick sample).

    Yields
    ------
    dict
        Problem documents, as :func:`random_problem` returns them.
    """
    for item in campaign_draws(family, count, seed, **knobs):
        yield item.doc


def with_value(doc: dict, value) -> dict:
    """A copy of ``doc`` with the family's searched key (:data:`SEARCHED`) set to ``value``."""
    out = copy.deepcopy(doc)
    family = out["observer"]["family"]
    out["observer"][SEARCHED[family]] = value if value == "max" else float(value)
    return out


def fixed_values(family: str, found: float, fractions) -> list[float]:
    """The fixed values to try on the feasible side of a certified max.

    Parameters
    ----------
    family : str
    found : float
        The certified max (decay for lti-uio, alpha for sampled-data, mu for ltv-auid), or a
        limit from theory.
    fractions : sequence of float
        In (0, 1); near 1 is near ``found``.

    Returns
    -------
    list of float
        lti-uio: ``found + (1 - f)(1 - found)`` (above the max decay, slower); sampled-data and
        ltv-auid: ``f * found`` (below the max). Values that would leave the open range of
        the parameter are dropped.
    """
    out = []
    for f in fractions:
        if family == "lti-uio":
            v = found + (1.0 - f) * (1.0 - found)
            ok = found < v < 1.0
        else:
            v = f * found
            ok = 0.0 < v < found and (family != "sampled-data" or v < 1.0)
        if ok and math.isfinite(v):
            out.append(float(v))
    return out


def feasible_side(family: str) -> str:
    """``"above"`` (lti-uio: slower decays) or ``"below"`` (alpha, mu) the certified max."""
    return "above" if family == "lti-uio" else "below"
