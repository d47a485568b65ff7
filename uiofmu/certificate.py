"""The certificate of a design: the LMI re-check plus checks at the stored matrices.

A design is certified only when every check holds. Each check is a number, a bound and a
direction, evaluated with numpy on the matrices the runtime will use (not on the solver's
variables alone), and all of them go into the card.

A verdict never depends on the BLAS kernel: a definiteness check (``Q > 0``) holds only when its
smallest eigenvalue clears :data:`~uiofmu.runtime.tolerances.ROUNDING_FACTOR` times the bound of
its own rounding error (:func:`rounding_floor`, from the sizes and magnitudes of the matrices), so a
check that holds proves the exact inequality at the stored matrices, and identities are judged
relative to the magnitudes of the products they cancel (:func:`magnitude`), far above their rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .runtime.errors import InfeasibleError
from .lmi import LmiSolution, accurate_optimum
from .runtime.tolerances import IDENTITY_RTOL, LMI_MARGIN, ROUNDING_FACTOR, VERIFY_FRACTION

#: The unit round-off of double precision.
EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class Check:
    """``value <= bound`` (``at_most``) or ``value >= bound``."""

    name: str
    value: float
    bound: float
    at_most: bool = True
    #: The bound of the rounding error of ``value`` (0: not derived); the bound is at least
    #: ``ROUNDING_FACTOR`` times it.
    floor: float = 0.0

    @property
    def holds(self) -> bool:
        """Whether the check passes."""
        return bool(self.value <= self.bound if self.at_most else self.value >= self.bound)

    def to_data(self) -> dict:
        """JSON-ready form."""
        out = {"value": self.value, "bound": self.bound, "relation": "<=" if self.at_most else ">=",
               "holds": self.holds}
        if self.floor:
            out["rounding_floor"] = self.floor
        return out

    def explain(self) -> str:
        """``name = value (needs >= bound)``, and what the bound comes from when rounding sets it."""
        text = f"{self.name} = {self.value:.3g} (needs {'<=' if self.at_most else '>='} {self.bound:.3g}"
        if self.floor and math.isclose(self.bound, ROUNDING_FACTOR * self.floor):     # the floor set the bound
            text += (f": {ROUNDING_FACTOR:g}x the rounding floor {self.floor:.3g} of its evaluation in double "
                     "precision, so that no BLAS kernel's rounding can decide it")
        return text + ")"


def round_up(value: float, digits: int) -> float:
    """``value`` rounded up to ``digits`` significant digits: a bound stays a bound, and a figure that
    rounding moves in its last bits prints the same on every machine (unless it sits on a boundary)."""
    if not (value > 0 and math.isfinite(value)):
        return value
    scale = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return math.ceil(value / scale * (1 - 4 * EPS)) * scale


def magnitude(*products) -> float:
    """``sum_i || |A_i1| |A_i2| ... ||_F``: the size of the terms an identity cancels.

    Each argument is a sequence of matrices whose product is one term; a residual of rounding is
    at most a small multiple of ``EPS`` times this, whatever the order of the arithmetic.
    """
    total = 0.0
    for factors in products:
        term = np.abs(np.asarray(factors[0], dtype=float))
        for f in factors[1:]:
            term = term @ np.abs(np.asarray(f, dtype=float))
        total += float(np.sqrt((term * term).sum()))
    return total


def rounding_floor(Q: np.ndarray, terms: np.ndarray, length: int) -> np.ndarray:
    """The bound of the rounding error of ``eig_min(Q)`` evaluated in double precision.

    ``Q`` is a sum of products whose absolute values add up to ``terms`` (entrywise, e.g.
    ``rho^2 |X| + |N|' |X| |N|`` for ``rho^2 X - N' X N``), each entry an inner product of at most
    ``length`` roundings. The evaluation errs by at most ``gamma_length * |terms|`` entrywise
    (Higham, Accuracy and Stability, (3.13)) and the symmetric eigenvalue solver by a small multiple
    of ``n EPS ||Q||`` (a backward-stable reduction); both in the Frobenius norm, which bounds the
    2-norm. Works on stacks (``(..., n, n)``).

    Returns
    -------
    numpy.ndarray or float
        One floor per matrix of the stack.
    """
    n = Q.shape[-1]
    fro = lambda x: np.sqrt((x * x).sum(axis=(-2, -1)))    # noqa: E731
    gamma = length * EPS / (1.0 - length * EPS)
    return gamma * fro(terms) + 4.0 * n * EPS * fro(Q)


def definite_check(name: str, Q: np.ndarray, terms: np.ndarray, length: int, margin: float = LMI_MARGIN,
                   verify_fraction: float = VERIFY_FRACTION, factor: float = ROUNDING_FACTOR) -> Check:
    """``Q > 0`` by its smallest eigenvalue, with margin over its own rounding.

    Holds when ``eig_min(Q) >= max(verify_fraction * margin, factor * floor)``, ``floor`` from
    :func:`rounding_floor`: with ``factor > 1`` the exact ``Q`` at the stored matrices is positive
    definite, and the verdict is the same under every BLAS kernel unless the value sits within the
    floor of the bound.
    """
    Q = 0.5 * (Q + Q.T)
    floor = float(rounding_floor(Q, terms, length))
    return Check(name, float(np.linalg.eigvalsh(Q)[0]), max(verify_fraction * margin, factor * floor),
                 at_most=False, floor=floor)


def identity_check(name: str, residual: np.ndarray, scale: float, rtol: float = IDENTITY_RTOL) -> Check:
    """An identity that must hold exactly: ``||residual|| <= rtol * max(1, scale)`` (the 2-norm: of a matrix its
    largest singular value, the LAPACK call ``numpy.linalg.norm`` makes, without its wrappers)."""
    if not residual.size:
        return Check(name, 0.0, rtol * max(1.0, scale))
    size = np.linalg.svd(residual, compute_uv=False).max() if residual.ndim == 2 else np.linalg.norm(residual, 2)
    return Check(name, float(size), rtol * max(1.0, scale))


def identity_checks(*items, rtol: float = IDENTITY_RTOL) -> list[Check]:
    """:func:`identity_check` of each ``(name, residual, scale)``, the matrix residuals of one shape measured by one
    stacked SVD: numpy runs the same LAPACK call on each matrix of a stack as on the matrix alone, so each value is
    :func:`identity_check`'s to the last bit, for a fraction of the calls' overhead."""
    sizes: list = [None] * len(items)
    groups: dict = {}
    for i, (_, residual, _) in enumerate(items):
        if residual.size and residual.ndim == 2:
            groups.setdefault(residual.shape, []).append(i)
    for rows in groups.values():
        top = np.linalg.svd(np.array([items[i][1] for i in rows], dtype=float), compute_uv=False).max(axis=-1)
        for i, value in zip(rows, top):
            sizes[i] = float(value)
    return [identity_check(name, residual, scale, rtol) if size is None else Check(name, size, rtol * max(1.0, scale))
            for (name, residual, scale), size in zip(items, sizes)]


def lyapunov_check(name: str, N: np.ndarray, X: np.ndarray, rho: float, X_prev: np.ndarray | None = None,
                   margin: float = LMI_MARGIN, verify_fraction: float = VERIFY_FRACTION) -> Check:
    """``rho^2 X_prev - N' X N > 0``: the decay ``||e_{k+1}||_X <= rho ||e_k||_{X_prev}`` at the
    stored ``N`` (``X_prev = X`` for a common Lyapunov matrix), decided with margin over its
    rounding (:func:`definite_check`)."""
    X_prev = X if X_prev is None else X_prev
    aN, n = np.abs(N), len(N)
    terms = rho * rho * np.abs(X_prev) + aN.T @ np.abs(X) @ aN
    return definite_check(name, rho * rho * X_prev - N.T @ X @ N, terms, 2 * n + 2, margin, verify_fraction)


def decay_check(rho: float) -> Check:
    """``rho < 1``: a decay bound of 1 or more certifies no convergence, whatever else holds."""
    return Check("decay bound < 1", float(rho), 1.0 - 2.0 ** -52)


def _spectra(lyapunov) -> np.ndarray:
    """The eigenvalues of each Lyapunov matrix of a stack (one row per matrix, ascending)."""
    P = np.asarray(lyapunov, dtype=float).reshape(-1, *np.shape(lyapunov)[-2:])
    return np.linalg.eigvalsh(0.5 * (P + np.swapaxes(P, -1, -2)))


def overshoot(lyapunov) -> float:
    """``sqrt(eig_max / eig_min)`` over the Lyapunov matrices of a certificate (one, or a stack of one
    per interval or mode): the ``overshoot_bound`` of ``||e_k|| <= overshoot * decay**k * ||e_0||``."""
    eig = _spectra(lyapunov)
    return float(np.sqrt(eig.max() / eig.min()))


#: Significant digits of a figure the problem determines to the solver's full tolerance, and the
#: ``overshoot_digits`` of one it does not determine at all (read off whichever point the solver stopped at).
FIGURE_DIGITS, UNDETERMINED = 4, 0

#: Significant digits of a figure read off the least objective at a held margin and reproduced to
#: :data:`~uiofmu.runtime.tolerances.HELD_AGREEMENT` (the last digit is then the problem's unless the value sits
#: within that agreement of a rounding boundary).
HELD_FIGURE_DIGITS = 2


def figure_digits(solution: LmiSolution, spread: float = 1.0) -> int:
    """The significant digits that a figure read off ``solution``'s point (the overshoot) has on every machine.

    :data:`FIGURE_DIGITS` for a closed form, or for the optimum of the system's own objective that
    CLARABEL reached to its full tolerance (``optimal``) with normalisations held to
    :data:`~uiofmu.runtime.tolerances.FIGURE_RTOL`; :data:`HELD_FIGURE_DIGITS` for the least objective at
    a held margin whose figure was reproduced (:meth:`uiofmu.lmi.LmiSystem.least_at_margin`);
    :data:`UNDETERMINED` for anything else (an ``optimal_inaccurate`` optimum of a plain solve, a least
    objective at a held margin not reproduced, the point of largest margin, a point reused from
    another value, an optimum whose variables are so large that the solver's tolerance leaves its
    normalisations loose): such a figure moved by factors between BLAS kernels (6.4 against 550 on a
    plant at the edge), so no digit of it is the problem's. ``spread`` is the system's
    :attr:`~uiofmu.lmi.LmiSystem.figure_spread`.
    """
    if solution.status.startswith("closed form"):
        return FIGURE_DIGITS
    if solution.held and solution.reproduced:
        return HELD_FIGURE_DIGITS
    if accurate_optimum(solution, spread):
        return FIGURE_DIGITS
    return UNDETERMINED


#: What follows an overshoot the problem does not determine (:data:`UNDETERMINED`) where it is printed.
UNDETERMINED_NOTE = "(this point's; not determined by the problem)"


def figure_text(value: float, digits: int) -> str:
    """``value`` to ``digits`` significant digits, in plain notation where it fits (``290``, ``36``, ``6.452``)."""
    rounded = float(f"{value:.{digits}g}")
    if not (math.isfinite(rounded) and 1e-4 <= abs(rounded) < 1e6):
        return f"{rounded:.{digits}g}"
    return np.format_float_positional(rounded, trim="-")


def overshoot_text(data: dict) -> str:
    """A card's ``overshoot_bound`` to the digits its design determines (``overshoot_digits``; 4 when absent);
    one the problem does not determine (``overshoot_digits`` 0) to 2 digits, followed by :data:`UNDETERMINED_NOTE`."""
    digits = data.get("overshoot_digits")
    value = float(data["overshoot_bound"])
    if digits == UNDETERMINED:
        return f"{figure_text(value, 2)} {UNDETERMINED_NOTE}"
    return figure_text(value, int(digits or FIGURE_DIGITS))


def overshoot_check(claimed, lyapunov) -> Check:
    """``overshoot_bound >= sqrt(eig_max / eig_min)`` over the Lyapunov matrices the certificate uses.

    The bound ``||e_k|| <= overshoot * decay**k * ||e_0||`` holds with that ratio (:func:`overshoot`);
    a card whose ``overshoot_bound`` is smaller claims more than its certificate proves. The
    eigenvalues are moved by their rounding bound (``4 n eps max |eig|``) toward the smaller ratio,
    so a bound computed from the same matrices on another machine passes, and a non-finite claim fails.

    Parameters
    ----------
    claimed : float
        The card's ``overshoot_bound``.
    lyapunov : array_like
        The certificate's Lyapunov matrix, or a stack of them (one per interval or mode).
    """
    eig = _spectra(lyapunov)
    slack = 4 * eig.shape[-1] * EPS * float(np.abs(eig).max())
    low, high = float(eig.min()) + slack, float(eig.max()) - slack
    needed = math.sqrt(max(high, low) / low) if low > 0 else math.inf
    try:
        value = float(claimed)
    except (TypeError, ValueError):
        value = math.nan
    return Check("overshoot_bound >= sqrt(eig_max / eig_min) of the Lyapunov matrices",
                 value if math.isfinite(value) else -math.inf, needed, at_most=False)


def positive_check(name: str, X: np.ndarray, margin: float = LMI_MARGIN,
                   verify_fraction: float = VERIFY_FRACTION) -> Check:
    """``X > 0`` by its smallest eigenvalue, with margin over its rounding (:func:`definite_check`)."""
    return definite_check(name, X, np.abs(X), 1, margin, verify_fraction)


def certificate(solution: LmiSolution, checks: list[Check], label: str, solver: str = "CLARABEL") -> dict:
    """Assemble the card's ``certificate`` entry and insist that it verifies.

    Parameters
    ----------
    solution : LmiSolution
        The (already re-checked) LMI solution.
    checks : list of Check
        Checks at the stored matrices.
    label : str
        Names the design in the error message.
    solver : str
        What found the point (``"none"`` for a closed form, whose point is re-checked all the same).

    Returns
    -------
    dict

    Raises
    ------
    InfeasibleError
        When a check fails: the design is not certified.
    """
    failed = [c for c in checks if not c.holds]
    if failed:
        raise InfeasibleError(f"{label}: the certificate does not survive the re-check at the stored matrices: "
                              + "; ".join(c.explain() for c in failed))
    return {
        "solver": solver,
        "status": solution.status,
        "parameters": solution.parameters,
        "lmi_margin": solution.margin,
        "verify_fraction": VERIFY_FRACTION,
        "lmi_eig_min": solution.eig_min,
        "checks": {c.name: c.to_data() for c in checks},
        "verified": bool(solution.verified and not failed),
        "solve_time_s": solution.solve_time,
    }


def geometric_bound(card, e0: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``M delta^k ||e_0||`` for k = 0..len(d)-1: the bound of designs with exact decoupling
    (it holds whatever the unknown input)."""
    k = np.arange(len(d))
    return card.data["overshoot_bound"] * card.data["decay_bound"] ** k * float(np.linalg.norm(e0))
