"""What a design card's own problem determines, compared with what the card says.

A card carries the problem it was designed for. The plant's matrices (sampled at the design's
step where the family samples), the schedule the FMU steps by, the plant's dimensions and the
figures the family derives from its certified variables (a decay bound from ``tau2``, a substep
from the gain) are all determined by that problem and those variables; the card's copies of them
are what the FMU runs and what it prints. A certificate re-checked at a copy that is not the
problem's proves convergence for another plant, or prints a bound nobody proved: each family
lists what its problem determines (``determined(problem, card_data)``) and :func:`consistency_checks`
compares the card with it, before the certificate's own checks run.

Numbers are compared relative to the larger of their magnitude and the magnitude of the terms
they are computed from (:class:`Determined`; a product that is zero in exact arithmetic is rounding
noise of its terms' size, :func:`product`), with :data:`SAME_RTOL`: far above the rounding of the
recomputation under any BLAS kernel (about 1e-15), far below any change that matters to a
certificate. What a pseudo-inverse of ``C E`` computes moves by ``cond(CE) eps`` between kernels and
is compared with a tolerance that grows with it (:func:`conditioned`). Strings, booleans, integers and
``None`` are compared exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .certificate import EPS, Check
from .matching import least_cost_matching
from .runtime.kernels import kernel_named
from .runtime.registry import FAMILIES
from .runtime.tolerances import IDENTITY_RTOL

#: How the name of a check of :func:`same_check` ends (after the card's path).
DETERMINED = " as the card's problem determines it (relative difference)"

#: Sections a card may leave out: without them it claims nothing of what they would say (a card designed before
#: uiofmu certified noise gains has no ``noise``; with one, every figure of it is re-checked).
CLAIMED_ONLY = ("noise",)
#: Largest relative difference between a card's copy and the value its problem determines.
SAME_RTOL = 1e-9


#: Rounding of a computation whose condition number is ``cond`` is below ``cond * EPS`` times its size;
#: :func:`conditioned` allows this many times that.
CONDITION_FACTOR = 100.0


@dataclass(frozen=True)
class Determined:
    """A value a card's problem determines, with the magnitude of the terms it is computed from
    (a matrix ``P A - T C`` of small norm whose gain ``T`` is large is compared relative to
    ``|P||A| + |T||C|``, since that is the size of its rounding) and its relative tolerance."""

    value: object
    scale: float = 0.0
    rtol: float = SAME_RTOL


#: Eigenvalues (and invariant zeros, fixed modes) of an ``n x n`` problem computed in double precision move
#: between BLAS kernels by up to ``(c n eps)^(1/k)`` of the matrix's size for a defective eigenvalue of a
#: Jordan block of size ``k``; :func:`eigen_rtol` allows ``k = n`` with ``c`` this.
EIGEN_FACTOR = 100.0


def eigen_rtol(n: int) -> float:
    """The relative tolerance of an eigenvalue of an ``n x n`` matrix recomputed on another machine:
    ``(EIGEN_FACTOR n eps)^(1/n)``, the perturbation bound of a Jordan block of size ``n`` (2e-7 for
    ``n = 2``, 4e-5 for 3, 5e-4 for 4; a forged eigenvalue moves far more), and never below
    :data:`SAME_RTOL`."""
    n = max(int(n), 1)
    return max(SAME_RTOL, (EIGEN_FACTOR * n * EPS) ** (1.0 / n))


@dataclass(frozen=True)
class Spectrum:
    """Eigenvalues a card records, compared as a multiset (any order) within :func:`eigen_rtol`.

    Attributes
    ----------
    value : numpy.ndarray
        Complex eigenvalues: shape ``(n,)``, or ``(count, n)`` for one list per matrix of a stack.
    scale : float
        The size they are relative to (the matrix's norm).
    rtol : float
    form : {"pairs", "radius", "radii"}
        How the card records them: ``[re, im]`` pairs (a list, or a list per matrix), the largest
        modulus (one number, over the whole stack), or the largest modulus per matrix.
    """

    value: np.ndarray
    scale: float
    rtol: float
    form: str = "pairs"


def spectrum(matrices, form: str = "pairs") -> Spectrum:
    """The eigenvalues of a matrix or a stack, as a card records them in ``form`` (see :class:`Spectrum`)."""
    M = np.asarray(matrices, dtype=float)
    scale = float(np.linalg.norm(M.reshape(-1, *M.shape[-2:]), 2, axis=(-2, -1)).max()) if M.size else 0.0
    return Spectrum(np.linalg.eigvals(M) if M.size else np.zeros(M.shape[:-1], complex), scale,
                    eigen_rtol(M.shape[-1]), form)


def computed_values(values, scale: float, n: int) -> Spectrum:
    """Eigenvalues or zeros a problem's analysis computes (a list, or a list per interval or mode), compared
    like :func:`spectrum`'s relative to ``scale`` (the size of the matrices they come from)."""
    return Spectrum(np.asarray(values, dtype=complex), float(scale), eigen_rtol(n))


def _spectrum_check(path: str, claimed, expected: Spectrum) -> Check:
    """The card's eigenvalues against a :class:`Spectrum`: the largest distance of a matched pair, relative
    to the spectrum's size (the matching minimises the distances, so any order passes)."""
    want = np.asarray(expected.value, dtype=complex)
    size = max(expected.scale, float(np.abs(want).max()) if want.size else 0.0, np.finfo(float).tiny)
    if expected.form in ("radius", "radii"):
        radii = np.abs(want).max(axis=-1) if want.size else np.zeros(want.shape[:-1])
        want_r = radii.max() if expected.form == "radius" and radii.size else radii
        got = _numbers(claimed)
        if got is None or got.shape != np.shape(want_r) or isinstance(claimed, bool):
            return Check(f"{path} (a {type(claimed).__name__}, its matrices give shape {np.shape(want_r)})"
                         + DETERMINED, math.inf, expected.rtol)
        diff = float(np.abs(got - want_r).max()) / size if got.size else 0.0
        return Check(path + DETERMINED, diff if math.isfinite(diff) else math.inf, expected.rtol)
    got = _numbers(claimed)
    if not want.size and got is not None and not got.size and not isinstance(claimed, bool):
        return Check(path + DETERMINED, 0.0, expected.rtol)              # none, as the problem gives none
    if got is None or got.shape != (*want.shape, 2) or isinstance(claimed, bool):
        return Check(f"{path} (shape {None if got is None else got.shape}, its problem gives {want.size} eigenvalues "
                     "as [re, im] pairs)" + DETERMINED, math.inf, expected.rtol)
    got = (got[..., 0] + 1j * got[..., 1]).reshape(-1, want.shape[-1] if want.ndim else 1)
    worst = 0.0
    for a, b in zip(got, want.reshape(got.shape)):
        cost = np.abs(a[:, None] - b[None, :])
        if not np.all(np.isfinite(cost)):
            return Check(path + DETERMINED, math.inf, expected.rtol)
        rows, cols = least_cost_matching(cost)
        worst = max(worst, float(cost[rows, cols].max()) if rows.size else 0.0)
    return Check(path + DETERMINED, worst / size, expected.rtol)


def conditioned(value, cond: float, scale: float = 0.0) -> Determined:
    """``value`` computed through a pseudo-inverse (or solve) of condition number ``cond``: compared
    with the tolerance ``max(SAME_RTOL, CONDITION_FACTOR * cond * EPS)``."""
    return Determined(value, scale, max(SAME_RTOL, CONDITION_FACTOR * float(cond) * EPS))


def condition(matrices) -> float:
    """The largest 2-norm condition number of a matrix or a stack of them (``inf`` if singular)."""
    M = np.asarray(matrices, dtype=float)
    M = M.reshape(-1, *M.shape[-2:])
    return float(max(np.linalg.cond(m) for m in M)) if M.size else 1.0


def dhat_record(C, A, B, E, w) -> dict:
    """dhat's matrices of stacked sampled plants ``A[k], B[k], E[k], w[k]`` (a stack of one for a
    single plant): ``Dy[k] = (C E[k])^+``, ``Yx[k] = C A[k]``, ``Yu[k] = C B[k]``, ``Yc[k] = C w[k]``
    (:func:`dhat_matrices`), each with the tolerance a re-computation is compared with."""
    A, B, E, w = (np.asarray(x, dtype=float) for x in (A, B, E, w))
    values = dhat_matrices(C, A, B, E, w)
    return {"Dy": conditioned(values["Dy"], condition(np.einsum("ij,kjl->kil", C, E))),
            "Yx": product(C, A, values["Yx"]), "Yu": product(C, B, values["Yu"]),
            "Yc": product(C, w[..., None], values["Yc"])}


def dhat_matrices(C, A, B, E, w) -> dict:
    """The values of :func:`dhat_record` alone (what a design stores; the tolerances are for the consistency
    check of a card)."""
    A, B, E, w = (np.asarray(x, dtype=float) for x in (A, B, E, w))
    CE = np.einsum("ij,kjl->kil", C, E)
    return {"Dy": np.array([np.linalg.pinv(m) for m in CE]), "Yx": np.einsum("ij,kjl->kil", C, A),
            "Yu": np.einsum("ij,kjl->kil", C, B), "Yc": np.einsum("ij,kjl->kil", C, w[..., None])[..., 0]}


def product(C, X, value=None) -> Determined:
    """``C @ X[k]`` for a stack ``X`` (``value``, when already computed: its shape is kept), compared relative to
    ``max(|C| |X[k]|)`` (the size of its terms: an entry that is zero in exact arithmetic is computed as rounding of
    that size, or as exact zero, by different kernels)."""
    X = np.asarray(X, dtype=float)
    value = np.einsum("ij,kjl->kil", C, X) if value is None else value
    terms = np.einsum("ij,kjl->kil", np.abs(C), np.abs(X))
    return Determined(value, float(terms.max()) if terms.size else 0.0)


def first(record: dict) -> dict:
    """The entries of a record of stacks of one (:func:`dhat_record` of a single plant), unstacked."""
    return {k: replace(v, value=v.value[0]) for k, v in record.items()}


def _numbers(value) -> np.ndarray | None:
    """``value`` as a float array, or None when it is not numeric (or ragged)."""
    if isinstance(value, (str, bool, dict)) or value is None:
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return None


def same_check(path: str, claimed, expected) -> Check:
    """``claimed`` (the card's) equals ``expected`` (what its problem determines).

    Parameters
    ----------
    path : str
        The card's key, dotted (``matrices.A_sampled``, ``schedule.dt``).
    claimed : object
        The card's value (anything a JSON document holds; missing: ``None``).
    expected : object or Determined
        Numbers (scalars, lists, arrays) are compared by their largest difference relative to
        their magnitude; strings, booleans, integers and ``None`` exactly.

    Returns
    -------
    Check
        Its value is the relative difference (infinite for a different type, shape or text).
    """
    if isinstance(expected, Spectrum):
        return _spectrum_check(path, claimed, expected)
    scale, rtol = (expected.scale, expected.rtol) if isinstance(expected, Determined) else (0.0, SAME_RTOL)
    expected = expected.value if isinstance(expected, Determined) else expected
    if expected is None or isinstance(expected, (str, bool)) or (
            isinstance(expected, (int, np.integer)) and not isinstance(expected, bool)):
        integer = isinstance(expected, (int, np.integer)) and not isinstance(expected, bool)
        same = (isinstance(claimed, int) and not isinstance(claimed, bool) if integer else
                type(claimed) is type(expected)) and claimed == expected
        return Check(path + ("" if same else _found(claimed, expected)) + DETERMINED, 0.0 if same else math.inf,
                     0.0)
    want, got = _numbers(expected), _numbers(claimed)
    if want is None or got is None or got.shape != want.shape or isinstance(claimed, bool):
        shape = "missing" if claimed is None else f"shape {got.shape}" if got is not None else type(claimed).__name__
        return Check(f"{path} ({shape}, its problem gives shape {np.shape(expected)})" + DETERMINED, math.inf, rtol)
    if not want.size:
        return Check(path + DETERMINED, 0.0, rtol)
    size = max(float(np.abs(want).max()), scale, np.finfo(float).tiny)
    diff = float(np.abs(got - want).max()) / size
    return Check(path + DETERMINED, diff if math.isfinite(diff) else math.inf, rtol)


def _found(claimed, expected) -> str:
    """`` (found X, its problem gives Y)`` for a mismatch compared exactly: each at most 40 characters,
    from where two texts first differ."""
    at = 0
    if isinstance(claimed, str) and isinstance(expected, str):
        at = next((i for i, (a, b) in enumerate(zip(claimed, expected)) if a != b), min(len(claimed), len(expected)))
        at = max(0, at - 10)
    lead = "..." if at else ""
    return f" (found {lead}{repr(claimed[at:] if at else claimed)[:40]}, its problem gives " \
           f"{lead}{repr(expected[at:] if at else expected)[:40]})"


def _lookup(data, path: str):
    """The card's value at a dotted path whose keys may end in list indices (``a.b[2].c``; ``None``
    where a key or an index is missing)."""
    for part in path.split("."):
        key, *indices = part.split("[")
        if not isinstance(data, dict) or key not in data:
            return None
        data = data[key]
        for index in indices:
            i = int(index.rstrip("]"))
            if not isinstance(data, list) or not 0 <= i < len(data):
                return None
            data = data[i]
    return data


def consistency_checks(card_data: dict, expected: dict) -> list:
    """One :func:`same_check` per entry of ``expected`` (dotted card paths to values; a dict value
    is compared key by key, and the card's table must have no other keys; a list of dicts element by
    element, the card's list of the same length).

    Parameters
    ----------
    card_data : dict
        The card's document.
    expected : dict
        What the card's problem determines.

    Returns
    -------
    list of Check
    """
    out = []
    for path, value in expected.items():
        if path.split(".")[0] in CLAIMED_ONLY and path.split(".")[0] not in card_data:
            continue                                  # a section the card leaves out claims nothing
        if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            claimed = _lookup(card_data, path)
            if not isinstance(claimed, list) or len(claimed) != len(value):
                out.append(Check(f"{path} (a list of {len(value)} tables)" + DETERMINED, math.inf, 0.0))
                continue
            out += consistency_checks(card_data, {f"{path}[{i}]": v for i, v in enumerate(value)})
        elif isinstance(value, dict):
            claimed = _lookup(card_data, path)
            extra = sorted(set(claimed) - set(value)) if isinstance(claimed, dict) else []
            if not isinstance(claimed, dict) or extra:
                out.append(Check(f"{path}" + (f" (with {', '.join(map(str, extra))[:80]})" if extra else "")
                                 + DETERMINED, math.inf, 0.0))
                continue
            out += consistency_checks(card_data, {f"{path}.{k}": v for k, v in value.items()})
        else:
            out.append(same_check(path, _lookup(card_data, path), value))
    return out


#: Numbers of an existence analysis recomputed on another machine. Those of :data:`SPECTRAL_KEYS` (zeros, fixed
#: modes, their moduli and limits, PBH margins) are compared to ``eigen_rtol(n)`` of the larger of their magnitude
#: and the largest such number of their condition (at least the smaller of 1 and the plant's size,
#: :func:`plant_scale`: a zero near 0 of a Jordan block is rounding of that size; a PBH margin, the smallest
#: singular value of ``[A - z I; C]``, moves at most as its mode ``z`` does); every
#: other number (a step, a requested decay, a fraction, a premise figure from a long simulation, a residual that
#: is rounding) to ``EXISTENCE_RTOL`` of the larger of its magnitude and ``IDENTITY_RTOL`` times the plant's size.
EXISTENCE_RTOL = 1e-6

#: Keys of an existence condition's values that hold eigenvalues, zeros and what is computed from them.
SPECTRAL_KEYS = frozenset({"zeros", "moduli", "real_parts", "fixed_modes", "largest_modulus", "largest_fixed_modulus",
                           "fixed_eigenvalues", "fixed_modes_A1", "modes", "largest_zero_modulus", "switching_radius",
                           "alpha_limit", "mu_limit", "weakest_mode", "pbh_margins", "weakest_margin"})

#: Keys of an existence condition's values that are a choice of the computation, not a figure of the problem
#: (bases of subspaces, whose signs and rotations an SVD picks; the polynomial monomials' order; the
#: solver's word): not compared.
RECORD_KEYS = frozenset({"P", "Phat", "basis", "monomials", "status"})


def existence_checks(claimed, recomputed, n: int, scale: float = 1.0) -> list:
    """The card's ``existence`` against the analysis of its problem recomputed without a solver.

    Every condition the analysis decides without a solve must be the card's, in order, with the same
    name, verdict and requirement, and values equal to the numbers' tolerance; a condition that took a
    solve (``"solver": true``, e.g. sampled-data's certificate on ker C) is the solver's record and is not
    recomputed, unless its name is one the analysis decides itself. ``exists`` must be what the card's
    required verdicts say.

    Parameters
    ----------
    claimed : object
        The card's ``existence``.
    recomputed : Existence
        ``family.analyse(problem, solver=False).existence``.
    n : int
        The state dimension (the eigenvalue tolerance's, :func:`eigen_rtol`).
    scale : float
        The size of the plant's matrices (:func:`plant_scale`; see :data:`EXISTENCE_RTOL` for how the
        numbers are compared).

    Returns
    -------
    list of Check
    """
    want = recomputed.to_data()
    conditions = claimed.get("conditions") if isinstance(claimed, dict) else None
    if not isinstance(conditions, list) or not all(isinstance(c, dict) for c in conditions):
        return [Check("existence (not a table with a list of conditions)" + DETERMINED, math.inf, 0.0)]
    names = {c["name"] for c in want["conditions"]}
    kept = [c for c in conditions if not (c.get("solver") is True and c.get("name") not in names)]
    out = [same_check("existence.family", claimed.get("family"), want["family"]),
           same_check("existence.exists", claimed.get("exists"),
                      all(c.get("holds") is True for c in conditions if c.get("required") is not False))]
    if len(kept) != len(want["conditions"]):
        return out + [Check(f"existence.conditions ({len(kept)} decided without a solver, its problem gives "
                            f"{len(want['conditions'])})" + DETERMINED, math.inf, 0.0)]
    for i, (got, expected) in enumerate(zip(kept, want["conditions"])):
        at = f"existence.conditions[{i}]"
        out += [same_check(f"{at}.{key}", got.get(key), expected[key]) for key in ("name", "holds", "required")]
        values, claimed_values = expected["values"], got.get("values")
        if not isinstance(claimed_values, dict) or set(claimed_values) != set(values):
            out.append(Check(f"{at}.values (the keys of {expected['name']})" + DETERMINED, math.inf, 0.0))
            continue
        spectral = [abs(x) for x in _floats(values, SPECTRAL_KEYS)]
        tolerance = {"spectral": (eigen_rtol(n), max(spectral + [min(scale, 1.0)])),
                     "other": (EXISTENCE_RTOL, IDENTITY_RTOL * max(scale, 1.0))}
        out += [Check(f"{at}.values.{key} (in multiples of what is allowed)" + DETERMINED,
                      _difference(claimed_values[key], value, tolerance, key), 1.0)
                for key, value in values.items() if key not in RECORD_KEYS]
    return out


def _floats(value, keys: frozenset, inside: bool = False) -> list:
    """Every finite float of a JSON value under one of ``keys`` (at any depth)."""
    if isinstance(value, dict):
        return [x for k, v in value.items() for x in _floats(v, keys, inside or k in keys)]
    if isinstance(value, list):
        return [x for v in value for x in _floats(v, keys, inside)]
    return [value] if inside and isinstance(value, float) and math.isfinite(value) else []


def plant_scale(plant_table) -> float:
    """The size of a problem's plant: the largest entry of its ``A`` (of every mode and scheduling part too; at
    least ``IDENTITY_RTOL``), the size of the rounding of its zeros and fixed modes."""
    if not isinstance(plant_table, dict):
        return 1.0
    tables = [plant_table, *(t for key in ("modes", "scheduling") for t in (plant_table.get(key) or [])
                             if isinstance(t, dict))]
    entries = [_numbers(t.get("A")) for t in tables]
    return max([IDENTITY_RTOL] + [float(np.abs(a).max()) for a in entries
                                  if a is not None and a.size and np.all(np.isfinite(a))])


def _difference(claimed, expected, tolerance: dict, key: str = "") -> float:
    """The largest difference of two JSON values as a multiple of what is allowed: a number under a key of
    :data:`SPECTRAL_KEYS` within ``rtol * max(|x|, floor)`` of ``tolerance["spectral"] = (rtol, floor)``, any
    other within ``tolerance["other"]``'s; keys of :data:`RECORD_KEYS` are not compared; everything else
    (structure, integers, strings, booleans, None) exactly (``inf`` when not equal)."""
    if isinstance(expected, dict):
        if not isinstance(claimed, dict) or set(claimed) != set(expected):
            return math.inf
        return max([_difference(claimed[k], v, tolerance, k) for k, v in expected.items() if k not in RECORD_KEYS]
                   + [0.0])
    if isinstance(expected, list):
        if not isinstance(claimed, list) or len(claimed) != len(expected):
            return math.inf
        return max([_difference(a, b, tolerance, key) for a, b in zip(claimed, expected)] + [0.0])
    if isinstance(expected, float) and not isinstance(claimed, bool) and isinstance(claimed, (int, float)):
        if math.isfinite(expected):
            rtol, floor = tolerance["spectral" if key in SPECTRAL_KEYS else "other"]
            diff = abs(float(claimed) - expected) / (rtol * max(abs(expected), floor))
            return diff if math.isfinite(diff) else math.inf
        return 0.0 if claimed == expected else math.inf
    return 0.0 if type(claimed) is type(expected) and claimed == expected else math.inf


def plant_record(problem) -> dict:
    """What every family's card records of its plant: the dimensions, the time base and the
    observer's initial estimate (zero unless the problem gives ``observer.xhat0``)."""
    plant = problem.plant
    xhat0 = problem.options.xhat0 if kernel_named(FAMILIES[problem.family].kernel).estimates_x else None
    return {"dims.n": plant.n, "dims.m": plant.m, "dims.p": plant.p, "dims.q": plant.q, "time": plant.time,
            "initial.xhat0": np.zeros(plant.n) if xhat0 is None else np.asarray(xhat0, dtype=float)}


__all__ = ["DETERMINED", "SAME_RTOL", "Determined", "Spectrum", "computed_values", "condition", "conditioned",
           "consistency_checks", "dhat_matrices", "dhat_record", "eigen_rtol", "existence_checks", "first",
           "plant_record", "plant_scale", "product", "same_check", "spectrum"]
