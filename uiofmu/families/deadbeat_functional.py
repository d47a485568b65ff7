"""Dead-beat functional observer for discrete LPV systems with unknown inputs (Fiacchini, Millerioux,
TAC 2013; seed 003).

For an LPV plant (:mod:`uiofmu.lpv_plant`) ``x+ = A(theta) x + E(theta) d``, ``y = C(theta) x + D(theta) d``
(the paper's B is our ``E``), a functional ``G x`` is read off a finite window of outputs, exactly,
whatever the unknown input. The steps, each reported by :func:`analyse` with its numbers:

1. The inherent delay ``r``: the smallest r >= 0 with rank condition (2),
   ``rank M(theta_{k:k+r}) - rank M(theta_{k+1:k+r}) = rank [E; D]``, where ``O(theta_{k:k+i})`` stacks
   ``C(theta_k), C(theta_{k+1}) A(theta_k), ...`` and ``M(theta_{k:k+i}) = [[D(theta_k), 0],
   [O(theta_{k+1:k+i}) E(theta_k), M(theta_{k+1:k+i})]]`` (the lower-left block as corrected in the
   seed notes). The matrices are polynomial in the window's theta values
   (:class:`uiofmu.polynomials.PolyMatrix`, exact coefficients); this version designs when ``M`` does
   not depend on theta (the unknown input reaches the outputs the same way at every step), so that
   the inverse system (4) is polynomial, and refuses otherwise, saying so.
2. The inverse system (4): ``Q = E(theta_k) Ibar M^+``, ``Ibar = [I_q 0]``, ``P = A(theta_k) - Q O(theta_{k:k+r})``,
   and ``x_{k+1} = P x_k + Q y_{k:k+r}`` for the true state. ``P`` is polynomial in the window; its
   monomials are the paper's ``rho`` and their coefficients the ``P_i`` of (8).
3. Algorithm 1 (iteration (16)): the maximal robust invariant subspace of ``{P_i}`` in ``ker G``, then
   ``Phat_i`` of (13) on a complement, and whether they generate a nilpotent semigroup, of class
   ``t``: then ``K = t - 1`` (Corollary 1); ``G P_i = 0`` for all i gives ``K = 0`` (Proposition 6).
4. The formula (Proposition 4, with the sum over j = 0..K-1 as in its proof): unrolling
   ``x_{j+1} = P_j x_j + Q_j y_{j:j+r}`` over ``K + 1`` steps, ``G`` times the product of the ``P``
   vanishes, and ``G x_k = sum_{j=k-K-1}^{k-1} G P_{k-1} ... P_{j+1} Q_j y_{j:j+r}``: coefficients on
   the outputs ``y_{k-K-1..k+r-1}``, polynomial in the same window of theta values.

The runtime (:mod:`uiofmu.runtime.window`) evaluates that finite window at every step, never the
recursion (3) (``P`` may be unstable: ``P_1`` of the paper's example has the eigenvalue -1). The
certificate is the identity itself, re-checked on simulations of the plant's own matrices with
random states, unknown inputs and theta sequences (:func:`checks`).

The exact arithmetic grows combinatorially: over a window of ``L`` steps the matrices are polynomials
in ``s L`` variables (``s`` scheduling components), with up to ``C(s L + d, d)`` monomials of degree at
most ``d`` (a product of ``L`` affine factors alone has up to ``(s + 1)^L``). The analysis and the design
each run inside one :func:`uiofmu.polynomials.work_limit`: a plant that would pass it is refused (a
:class:`~uiofmu.runtime.errors.ProblemError` naming the states, the components, the window and the
monomials) before the memory or the time it would take are spent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..certificate import Check
from ..existence import Condition, Existence, complex_list, format_complex
from ..lpv_plant import LpvPlant
from ..noise import certified, fir_system, peak_to_peak, recheck, section as noise_section
from ..polynomials import PolyMatrix, TooLarge, hstack, shifted, stack, work_limit
from ..runtime.card import MAX_POWER
from ..runtime.errors import InfeasibleError, ProblemError
from ..runtime.matrices import as_matrix
from ..runtime.tolerances import IDENTITY_RTOL, RANK_RTOL
from ..structure import product_radius, rank
from . import Analysis, DesignResult

NAME = "deadbeat-functional"
#: Most matrices (P_i, Phat_i) a condition's text lists one by one; its values hold them all.
MAX_LISTED = 8


@dataclass(frozen=True)
class Options:
    """Options of the dead-beat functional observer.

    Attributes
    ----------
    G : numpy.ndarray
        The functional to reconstruct, ``(d, n)``.
    dt : float
        The plant's period.
    max_delay : int
        Largest inherent delay r tried.
    gain_cap : float or None
        Bound on the formula's gains (the largest ``||F_t||_2`` of its coefficient matrices): the formula is
        a closed form, so a gain above it is refused, not reduced (:mod:`uiofmu.gains`).
    """

    G: np.ndarray
    dt: float
    max_delay: int
    gain_cap: float | None = None

    @property
    def step(self) -> float:
        """The communication step: the plant's period."""
        return self.dt


def parse_options(table, plant) -> Options:
    """Read ``[observer]``: ``G`` (a matrix, or ``"identity"`` for the whole state), ``max_delay``, ``gain_cap``."""
    if not isinstance(plant, LpvPlant):
        raise ProblemError('observer.family = "deadbeat-functional": the plant needs its [[plant.scheduling]] '
                           "tables (an LPV plant; a single table of zeros makes a linear plant one)")
    G = table.get("G")
    G = np.eye(plant.n) if G == "identity" else as_matrix(G, table.key("G"), cols=plant.n)
    if G.shape[0] == 0:
        raise ProblemError(f"{table.key('G')}: expected at least one row")
    max_delay = table.get("max_delay", plant.n)
    if isinstance(max_delay, bool) or not isinstance(max_delay, int) or not 0 <= max_delay <= 4 * plant.n:
        raise ProblemError(f"{table.key('max_delay')}: expected an integer from 0 to {4 * plant.n}, "
                           f"found {repr(max_delay)[:40]}")
    return Options(G, plant.dt, max_delay, table.scalar("gain_cap", None, low=0.0, open_low=True))


# -- polynomial matrices of the plant over a window -------------------------------------------
def window_matrix(plant: LpvPlant, name: str, lag: int, absolute: bool = False) -> PolyMatrix:
    """``name(theta_{k+lag})`` as a polynomial in the variables ``(lag, i)`` (of the absolute values of
    its parts with ``absolute``: what bounds the size of the terms of its products)."""
    f = np.abs if absolute else np.asarray
    return PolyMatrix.affine(f(getattr(plant, name)), {(lag, i): f(part[name]) for i, part in enumerate(plant.parts)})


class Windows:
    """``O(theta_{k:k+r})``, ``M(theta_{k:k+r})`` and ``M(theta_{k+1:k+r})`` for r = 0, 1, ..., each from
    those of ``r - 1``: the plant's matrices do not depend on k, so ``O(theta_{k+1:k+r})`` is
    ``O(theta_{k:k+r-1})`` with every lag moved by one (:func:`~uiofmu.polynomials.shifted`), and

    ``O(theta_{k:k+r}) = [C(theta_k); O(theta_{k+1:k+r}) A(theta_k)]``,
    ``M(theta_{k:k+r}) = [[D(theta_k), 0], [O(theta_{k+1:k+r}) E(theta_k), M(theta_{k+1:k+r})]]``

    (the recursion of the paper, lower-left block corrected): two products a step, no recursion.

    Parameters
    ----------
    plant : LpvPlant

    Attributes
    ----------
    r : int
        The delay reached (-1 before :meth:`advance`).
    O, M, M_next : PolyMatrix
        ``O(theta_{k:k+r})``, ``M(theta_{k:k+r})``, ``M(theta_{k+1:k+r})`` (None for r = 0).
    """

    def __init__(self, plant: LpvPlant, absolute: bool = False):
        self.plant, self.absolute = plant, absolute
        self.r = -1
        self.O = self.M = self.M_next = None

    def advance(self) -> "Windows":
        """From delay ``r`` to ``r + 1``."""
        plant, absolute = self.plant, self.absolute
        C, D = window_matrix(plant, "C", 0, absolute), window_matrix(plant, "D", 0, absolute)
        if self.r < 0:
            self.O, self.M = C, D
        else:
            O_next, self.M_next = shifted(self.O, 1), shifted(self.M, 1)
            top = hstack([D, PolyMatrix.constant(np.zeros((plant.p, self.M_next.shape[1])))])
            self.M = stack([top, hstack([O_next @ window_matrix(plant, "E", 0, absolute), self.M_next])])
            self.O = stack([C, O_next @ window_matrix(plant, "A", 0, absolute)])
        self.r += 1
        return self

    def at(self, r: int) -> "Windows":
        """Advanced to delay ``r`` (from where it is, ``r`` not below it)."""
        while self.r < r:
            self.advance()
        return self


def too_large(plant: LpvPlant, exc: TooLarge, stage: str, window: int) -> ProblemError:
    """The refusal of a plant whose exact arithmetic passes the limits of :mod:`uiofmu.polynomials`.

    Parameters
    ----------
    plant : LpvPlant
    exc : TooLarge
        What passed which limit, with its numbers.
    stage : str
        What was being computed (``"the inverse system of delay r = 5"``).
    window : int
        The steps of theta it spans.

    Returns
    -------
    ProblemError
    """
    s, L = plant.s, window
    return ProblemError(
        f"plant.scheduling: {stage} is too large to compute exactly (n = {plant.n} states, s = {s} scheduling "
        f"component(s), a window of L = {L} steps: its matrices are polynomials in s L = {s * L} variables, with "
        f"up to C(s L + d, d) monomials of degree d): {exc}; fewer scheduling components (or parts that are "
        "zero), a smaller plant or a smaller observer.max_delay would help")


def _finite(M, what: str) -> None:
    if not np.all(np.isfinite(M)):
        raise ProblemError(f"{what} overflows (the plant's matrices multiplied over the window exceed the double "
                           f"range; largest finite entry {float(np.abs(M[np.isfinite(M)]).max(initial=0.0)):.3g}): "
                           "rescale the plant (states, outputs or unknown input)")


#: A coefficient of a window matrix is rounding, not a dependence on theta, when it is at most this relative
#: to the size of the products it sums (the same polynomial of the absolute values): about 4500 eps, above the
#: rounding of sums of a few hundred products, far below any theta term the plant's data make.
STRUCTURAL_RTOL = 1e-12


def _constant(P: PolyMatrix, what: str, magnitude) -> np.ndarray:
    """The constant ``P`` is, once its entries that are rounding of their products are left out.

    Parameters
    ----------
    P : PolyMatrix
    what : str
        Its name in a refusal.
    magnitude : callable
        ``magnitude()``: the same polynomial of absolute values (computed only when ``P`` has theta terms).

    Raises
    ------
    ProblemError
        When a theta term is more than rounding: named with its size and the size of its products.
    """
    if P.is_constant(0.0):
        return P.coeffs.get((), np.zeros(P.shape))
    bound = magnitude()
    cleaned = P.without_rounding(bound, STRUCTURAL_RTOL)
    if cleaned.is_constant(0.0):
        return cleaned.coeffs.get((), np.zeros(P.shape))
    m, c = max(((m, c) for m, c in cleaned.coeffs.items() if m), key=lambda mc: float(np.abs(mc[1]).max()))
    at = np.unravel_index(int(np.argmax(np.abs(c))), c.shape)
    size = float(bound.coeffs[m][at])
    shown = sorted(cleaned.variables)[:4]
    raise ProblemError(f"{what} depends on theta (through {', '.join(f'theta_k+{l}[{i + 1}]' for l, i in shown)}; "
                       f"its largest theta coefficient, entry ({at[0] + 1}, {at[1] + 1}) of the term "
                       f"{_monomial_text(m)}, is {abs(float(c[at])):.3g} where its products add up to {size:.3g}: "
                       f"not rounding): the inverse system (4) is then rational in theta, which this version does "
                       "not design")


@dataclass(frozen=True)
class Inverse:
    """The inverse system of delay ``r``: ``x_{k+1} = P x_k + Q y_{k:k+r}`` (polynomials in ``(lag, i)``),
    and the sizes of the products each coefficient of ``P`` and ``Q`` sums (the same computation on absolute
    values): what tells a coefficient that is rounding from one the plant makes."""

    r: int
    P: PolyMatrix
    Q: PolyMatrix
    ranks: list
    P_size: PolyMatrix
    Q_size: PolyMatrix


def inverse_system(plant: LpvPlant, max_delay: int) -> tuple[Inverse | None, list]:
    """The smallest delay r with rank condition (2) and the matrices (4); the ranks tried.

    Raises
    ------
    ProblemError
        When ``M`` depends on theta, overflows, or the polynomials of a delay pass the limits of
        :mod:`uiofmu.polynomials` (:func:`too_large`).
    """
    target = rank(np.vstack([plant.E, plant.D]))
    tried, windows, sizes = [], Windows(plant), Windows(plant, absolute=True)
    for r in range(max_delay + 1):
        try:
            windows.advance()
            M = _constant(windows.M, f"M(theta_k:k+{r})", lambda: sizes.at(r).M)
            M1 = _constant(windows.M_next, f"M(theta_k+1:k+{r})", lambda: sizes.at(r).M_next) if r else \
                np.zeros((0, 0))
            _finite(M, f"M(theta_k:k+{r})")
            got = rank(M) - (rank(M1) if r else 0)
            tried.append({"r": r, "rank_M": rank(M), "rank_M_next": rank(M1) if r else 0, "rank_ED": target})
            if got == target:
                Ibar = np.hstack([np.eye(plant.q), np.zeros((plant.q, plant.q * r))])
                W = Ibar @ np.linalg.pinv(M, rcond=RANK_RTOL)
                Q = window_matrix(plant, "E", 0) @ W
                P = window_matrix(plant, "A", 0) - Q @ windows.O
                Q_size = window_matrix(plant, "E", 0, True) @ np.abs(W)
                P_size = window_matrix(plant, "A", 0, True) + Q_size @ sizes.at(r).O
                P, Q = P.without_rounding(P_size, STRUCTURAL_RTOL), Q.without_rounding(Q_size, STRUCTURAL_RTOL)
        except TooLarge as exc:
            raise too_large(plant, exc, f"the inverse system of delay r = {r}", r + 1) from None
        if got == target:
            for name, X in (("P", P), ("Q", Q)):
                for c in X.coeffs.values():
                    _finite(c, f"the inverse system's {name} (delay r = {r})")
            return Inverse(r, _nonempty(P.pruned(1e-15)), _nonempty(Q.pruned(1e-15)), tried, P_size, Q_size), tried
    return None, tried


def _nonempty(P: PolyMatrix) -> PolyMatrix:
    """``P``, with an explicit zero constant term when every coefficient is zero."""
    return P if P.coeffs else PolyMatrix.constant(np.zeros(P.shape))


# -- subspaces --------------------------------------------------------------------------------
def null_space(M: np.ndarray) -> np.ndarray:
    """An orthonormal basis of ``ker M`` (columns), rank by :data:`RANK_RTOL`."""
    if M.shape[0] == 0:
        return np.eye(M.shape[1])
    # a tall M (the stacked matrices of Algorithm 1) needs no left singular vectors: without them the
    # SVD holds (cols, cols) numbers, not (rows, rows)
    _, s, vt = np.linalg.svd(M, full_matrices=M.shape[0] < M.shape[1])
    k = int(np.sum(s > RANK_RTOL * max(1.0, float(s[0]) if s.size else 0.0)))
    return vt[k:].T


def invariant_subspace(mats: list, V: np.ndarray) -> tuple[np.ndarray, list]:
    """Algorithm 1, iteration (16): the maximal subspace of ``span V`` invariant under every matrix;
    its orthonormal basis and the dimensions of the iterates."""
    J, dims = V, [V.shape[1]]
    for _ in range(V.shape[0] + 1):
        if J.shape[1] == 0:
            break
        # x = J a with A_i J a in span J for every i: the kernel of the stacked (I - J J') A_i J
        proj = np.eye(J.shape[0]) - J @ J.T
        a = null_space(np.vstack([proj @ Ai @ J for Ai in mats]))
        J_next = np.linalg.qr(J @ a)[0] if a.shape[1] else np.zeros((J.shape[0], 0))
        dims.append(J_next.shape[1])
        if J_next.shape[1] == J.shape[1]:
            break
        J = J_next
    return J, dims


def complement(T: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the orthogonal complement of ``span T`` (orthonormal columns), from the
    canonical vectors in order (Gram-Schmidt, skipping the ones it already spans): when ``span T`` is
    spanned by canonical vectors, the complement is the other canonical vectors, as in the paper."""
    n = T.shape[0]
    basis = [T[:, i] for i in range(T.shape[1])]
    out = []
    for j in range(n):
        v = np.eye(n)[j]
        for b in basis + out:
            v = v - (b @ v) * b
        if np.linalg.norm(v) > 1e-8:
            out.append(v / np.linalg.norm(v))
        if len(out) == n - T.shape[1]:
            break
    return np.array(out).T if out else np.zeros((n, 0))


def nilpotency_class(mats: list) -> int | None:
    """The class t of the semigroup the matrices generate (every product of t of them is 0), or None
    when it is not nilpotent: ``V_0 = R^h``, ``V_{j+1} = sum_i P_i V_j``, t the first j with ``V_j = 0``."""
    h = mats[0].shape[0] if mats else 0
    V = np.eye(h)
    for t in range(0, h + 1):
        if V.shape[1] == 0:
            return t
        images = np.hstack([Pi @ V for Pi in mats])
        u, s, _ = np.linalg.svd(images, full_matrices=False) if images.size else (np.zeros((h, 0)), [], None)
        scale = max(1.0, max(float(np.abs(Pi).max()) for Pi in mats))
        k = int(np.sum(np.asarray(s) > RANK_RTOL * scale * max(1.0, float(np.abs(V).max()))))
        V = u[:, :k]
    return None if V.shape[1] else h + 1


#: Most products of one length :func:`lasting_product` forms.
MAX_PRODUCTS = 4096


def lasting_product(mats: list) -> tuple[tuple, np.ndarray, bool]:
    """Why matrices that are not a nilpotent semigroup (:func:`nilpotency_class` None) are not: a product of
    them that never vanishes: the indices ``(i_1, ..., i_L)`` applied in that order, the product
    ``P_{i_L} ... P_{i_1}``, and whether it has a non-zero eigenvalue (its powers never vanish).

    A finite set of matrices generates a nilpotent semigroup exactly when every product of them is nilpotent
    (Levitzki), so some product has a non-zero eigenvalue: the one of largest ``rho ** (1 / L)`` up to the
    dimension's length (:func:`uiofmu.structure.product_radius`, at most :data:`MAX_PRODUCTS` per length).
    When rounding hides it, the product of the dimension's length of largest norm, built one factor at a time.
    """
    h = mats[0].shape[0]
    radius, sequence = product_radius(mats, max_length=h, max_products=MAX_PRODUCTS)
    scale = max(1.0, max(float(np.abs(P).max()) for P in mats))
    if radius > RANK_RTOL ** (1.0 / max(len(sequence), 1)) * scale:
        return sequence, _product(mats, sequence), True
    sequence = ()
    for _ in range(h):
        sequence += (max(range(len(mats)), key=lambda i: np.linalg.norm(_product(mats, sequence + (i,)))),)
    return sequence, _product(mats, sequence), False


def _product(mats: list, sequence: tuple) -> np.ndarray:
    """``P_{i_L} ... P_{i_1}`` of the indices ``(i_1, ..., i_L)``."""
    out = np.eye(mats[0].shape[0])
    for i in sequence:
        out = mats[i] @ out
    return out


def _monomial_text(m: tuple) -> str:
    return "1" if not m else "·".join(f"θ_k+{lag}[{i + 1}]" + (f"^{p}" if p > 1 else "") for (lag, i), p in m)


def _listed(items: list, show, sep: str = "; ") -> str:
    """``show(i, item)`` of at most :data:`MAX_LISTED` items joined by ``sep`` (then how many in all)."""
    shown = sep.join(show(i, x) for i, x in enumerate(items[:MAX_LISTED]))
    return shown if len(items) <= MAX_LISTED else f"{shown}{sep}... ({len(items)} in all)"


def _analysis(problem):
    plant, opts = problem.plant, problem.options
    conds = []
    with work_limit():
        inv, tried = inverse_system(plant, opts.max_delay)
    ranks = "; ".join(f"r = {t['r']}: {t['rank_M']} - {t['rank_M_next']}" for t in tried)
    if inv is None:
        conds.append(Condition("inherent delay", False, True,
                               f"rank condition (2) fails for every r up to {opts.max_delay} "
                               f"(rank M - rank M' = {ranks}; needs rank [E; D] = {tried[0]['rank_ED']}): the "
                               "unknown input cannot be reconstructed, so no inverse system exists", {"tried": tried}))
        return Existence(NAME, tuple(conds)), None
    conds.append(Condition("inherent delay", True, True,
                           f"rank condition (2) holds with r = {inv.r} (rank M - rank M' = {ranks}; "
                           f"rank [E; D] = {tried[0]['rank_ED']})", {"r": inv.r, "tried": tried}))
    monomials = sorted(inv.P.coeffs, key=lambda m: (len(m), m))
    Pi = [inv.P.coeffs[m] for m in monomials]
    conds.append(Condition("P decomposition (8)", True, False,
                           "P(theta) = " + _listed(monomials, lambda i, m: f"{_monomial_text(m)}·P_{i + 1}", " + ")
                           + "; eigenvalues of "
                           + _listed(Pi, lambda i, P: f"P_{i + 1}: {format_complex(np.linalg.eigvals(P))}"),
                           {"monomials": [[[lag, i, p] for (lag, i), p in m] for m in monomials],
                            "P": [P.tolist() for P in Pi]}))
    G = opts.G
    kernel_short = all(np.abs(G @ P).max() <= IDENTITY_RTOL * max(1.0, np.abs(P).max()) for P in Pi)
    Tbar, dims = invariant_subspace(Pi, null_space(G))
    That = complement(Tbar)
    Phat = [That.T @ P @ That for P in Pi]
    t = nilpotency_class(Phat)
    conds.append(Condition("robust invariant subspace in ker G", True, False,
                           f"Algorithm 1 in ker G (dimension {dims[0]}): iterate dimensions {dims}, the maximal "
                           f"robust invariant subspace has dimension {Tbar.shape[1]}"
                           + (f", basis {np.round(Tbar.T, 6).tolist()}" if Tbar.shape[1] else ""),
                           {"dimensions": dims, "basis": Tbar.T.tolist(), "Phat": [P.tolist() for P in Phat]}))
    if kernel_short:
        conds.append(Condition("Proposition 6", True, False, "G P_i = 0 for every i: K = 0", {"K": 0}))
    if t is None:
        sequence, product, cycles = lasting_product(Phat)
        word = "·".join(f"Phat_{i + 1}" for i in reversed(sequence))
        conds.append(Condition("nilpotent semigroup", False, True,
                               "the matrices Phat_i (13) do not generate a nilpotent semigroup (eigenvalues "
                               + _listed(Phat, lambda i, P: f"Phat_{i + 1}: {format_complex(np.linalg.eigvals(P))}")
                               + f"): the product {word} (norm {np.linalg.norm(product, 2):.6g}, eigenvalues "
                               f"{format_complex(np.linalg.eigvals(product))}) "
                               + ("has a non-zero eigenvalue, so its powers never vanish" if cycles else
                                  f"of {len(sequence)} factors does not vanish (the dimension {len(product)} bounds "
                                  "the length of a vanishing product)")
                               + ": no finite window gives G x whatever the unknown input",
                               {"Phat_eigenvalues": [complex_list(np.linalg.eigvals(P)) for P in Phat],
                                "product": [i + 1 for i in sequence],
                                "product_norm": float(np.linalg.norm(product, 2)),
                                "product_eigenvalues": complex_list(np.linalg.eigvals(product))}))
        return Existence(NAME, tuple(conds)), None
    K = 0 if kernel_short else max(t - 1, 0)
    conds.append(Condition("nilpotent semigroup", True, True,
                           f"Phat_i generate a nilpotent semigroup of class t = {t}: K = {K}, G x_k from "
                           f"y_k-{K + 1}..y_k+{inv.r - 1}", {"t": t, "K": K}))
    return Existence(NAME, tuple(conds)), {"inverse": inv, "K": K, "t": t, "monomials": monomials}


def analyse(problem, solver: bool = True) -> Analysis:
    """Inherent delay r (2), inverse system (4), decomposition (8), Algorithm 1, nilpotency (Corollary 1)."""
    existence, data = _analysis(problem)
    return Analysis(existence, data or {})


# -- the formula ------------------------------------------------------------------------------
def window_length(r: int, K: int) -> int:
    """The outputs the formula reads: ``K + max(r, 1) + 1``."""
    return K + max(r, 1) + 1


def formula(G: np.ndarray, inv: Inverse, K: int, p: int, sizes: bool = False) -> tuple[PolyMatrix, int, int]:
    """``G x_k`` as coefficients on the output window, polynomial in the window's theta values.

    With ``sizes``, the same sums of products of ``|G|`` and the sizes of ``P`` and ``Q``
    (:class:`Inverse`): what each coefficient's terms add up to, so that a coefficient that is rounding
    of them (a theta term of a structurally zero product) is told from one the plant makes.

    Returns
    -------
    F : PolyMatrix
        ``(d, p L)``: ``G x_{newest - delay} = F(theta) [y_oldest; ...; y_newest]``, the variables
        ``(l, i)`` with ``l`` the position in the window (0 the oldest).
    L : int
        Window length ``K + max(r, 1) + 1``.
    delay : int
        ``max(r - 1, 0)``: ``G x`` of the point that many steps before the newest output.
    """
    r = inv.r
    L, delay = window_length(r, K), max(r - 1, 0)
    newest = delay                       # lags relative to k (G x_k): the newest output is y_{k+delay}
    oldest = newest - L + 1
    d = G.shape[0]
    G, P, Q = (np.abs(G), inv.P_size, inv.Q_size) if sizes else (G, inv.P, inv.Q)
    out = PolyMatrix((d, p * L), {})
    for j in range(-K - 1, 0):           # x_{j+1} = P_j x_j + Q_j y_{j:j+r}, lags relative to k
        term = PolyMatrix.constant(G)
        for i in range(-1, j, -1):       # G P_{k-1} ... P_{j+1}
            term = term @ shifted(P, i)
        term = term @ shifted(Q, j)      # (d, p (r + 1)), on y_{j..j+r}
        pos = j - oldest
        out = out + hstack([PolyMatrix.constant(np.zeros((d, p * pos))), term,
                            PolyMatrix.constant(np.zeros((d, p * (L - pos - r - 1))))])
    coeffs = {}
    for m, c in (out if sizes else out.pruned(1e-14)).coeffs.items():
        coeffs[tuple(sorted(((lag - oldest, i), pw) for (lag, i), pw in m))] = c
    return PolyMatrix((d, p * L), coeffs or {(): np.zeros((d, p * L))}), L, delay


def to_arrays(F: PolyMatrix, L: int, s: int) -> tuple[np.ndarray, np.ndarray]:
    """The card's ``F`` (terms, d, p L) and ``Fexp`` (terms, L, s) of a window formula."""
    terms = sorted(F.coeffs, key=lambda m: (len(m), m))
    exps = np.zeros((len(terms), L, s))
    for t, m in enumerate(terms):
        for (pos, i), pw in m:
            exps[t, pos, i] = pw
    return np.array([F.coeffs[m] for m in terms]), exps


def evaluate(F: np.ndarray, exps: np.ndarray, ys: np.ndarray, thetas: np.ndarray) -> np.ndarray:
    """The formula on one window (``ys`` (L, p), ``thetas`` (L, s), oldest first)."""
    weights = np.prod(thetas[None] ** exps, axis=(1, 2))
    return np.tensordot(weights, F, axes=1) @ ys.ravel()


def simulate(mats: dict, x0, d, thetas):
    """The LPV plant of a card's matrices (``A_parts`` etc., part 0 the constant one) on given
    unknown inputs and theta sequence: states (K+1, n) and outputs (K, p)."""
    def at(name, th):
        parts = np.asarray(mats[name])
        return parts[0] + np.tensordot(th, parts[1:], axes=1)
    xs, ys = [np.asarray(x0, dtype=float)], []
    for dk, th in zip(d, thetas):
        x = xs[-1]
        ys.append(at("C_parts", th) @ x + at("D_parts", th) @ dk)
        xs.append(at("A_parts", th) @ x + at("E_parts", th) @ dk)
    return np.array(xs), np.array(ys)


#: Simulations and steps of the certificate's re-check.
CHECK_RUNS, CHECK_STEPS = 12, 12


def checks(matrices: dict, schedule: dict, seed: int = 0) -> list:
    """The certificate: ``gx = G x_{k - delay}`` on simulations of the plant's own matrices, with
    random initial states, unknown inputs and theta sequences (normal, scale 1), every window of
    every run; the largest residual relative to ``max(1, |G x|, |F| |y|)`` must be at most
    :data:`IDENTITY_RTOL` (round-off of the products)."""
    F, exps, G = (np.asarray(matrices[k], dtype=float) for k in ("F", "Fexp", "G"))
    L, delay = int(schedule["length"]), int(schedule["delay"])
    n, s = G.shape[1], exps.shape[2]
    q = np.asarray(matrices["E_parts"]).shape[2]
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(CHECK_RUNS):
        steps = L + CHECK_STEPS
        thetas = rng.normal(size=(steps, s))
        xs, ys = simulate(matrices, rng.normal(size=n), rng.normal(size=(steps, q)), thetas)
        for k in range(L - 1, steps):
            got = evaluate(F, exps, ys[k - L + 1:k + 1], thetas[k - L + 1:k + 1])
            want = G @ xs[k - delay]
            weights = np.prod(np.abs(thetas[k - L + 1:k + 1])[None] ** exps, axis=(1, 2))
            sizes = np.tensordot(weights, np.abs(F), axes=1) @ np.abs(ys[k - L + 1:k + 1]).ravel()
            scale = max(1.0, float(np.abs(want).max()), float(sizes.max()))
            residual = float(np.abs(got - want).max()) / scale
            worst = max(worst, residual) if np.isfinite(residual) else np.inf     # an overflowed run fails
    return [Check("identity G x = f(y, theta) on simulated runs (relative)", worst, IDENTITY_RTOL)]


def verify(card) -> list:
    """Re-check a card's identity on fresh simulations of its plant matrices (no solver)."""
    return checks(card.data["matrices"], card.data["schedule"], seed=1) + noise_checks(card.data)


def gain_figures(card_data: dict) -> tuple:
    """The formula's coefficient matrices (one per theta monomial, on the window's outputs), ``||C||`` and
    ``||G||``: the formula maps outputs to ``G x`` in one go (:mod:`uiofmu.gains`)."""
    m = card_data["matrices"]
    C = np.asarray(m["C"], dtype=float)
    return [m["F"]], float(np.linalg.norm(C, 2)) if C.size else 0.0, float(np.linalg.norm(np.asarray(m["G"]), 2))


def _parts(plant) -> dict:
    """The plant's matrices as the re-check simulates them: ``X_parts[0]`` the constant part, then
    one per scheduling component."""
    return {f"{k}_parts": np.array([getattr(plant, k)] + [part[k] for part in plant.parts]) for k in "AECD"}


#: Above this many states of the filter's realisation (outputs times the window), ``gain_y`` is the sum of the
#: coefficients' norms, which bounds it without a Riccati equation of that size.
FIR_STATES = 120

#: Why a formula with theta terms has no noise gain, and what the process noise's gain is not.
THETA_NOISE = ("gain_y: not certified: the formula's coefficients depend on theta, so its gain does too (the "
               "problem bounds no theta)")
NO_W = "gain_w: the problem declares no process noise"


def coefficients(F: np.ndarray, p: int) -> list:
    """The window formula's coefficients of a theta-free formula, newest output first: ``K_j`` multiplies
    ``y_(k-j)`` of the window (``F`` lists the outputs oldest first)."""
    L = F.shape[2] // p
    return [F[0][:, (L - 1 - j) * p:(L - j) * p] for j in range(L)]


def noise_of(F: np.ndarray, exps: np.ndarray, p: int) -> dict:
    """The card's ``noise`` section. A noise ``v`` on the outputs reaches the formula's value as the filter
    ``gx_k - G x_(k-delay) = sum_j K_j v_(k-j)`` of its coefficients (:func:`coefficients`): its l2 gain is
    certified by the bounded real lemma on the filter's realisation (:func:`uiofmu.noise.fir_system`), its
    peak-to-peak gain is ``sum_j ||K_j||_2``; a formula with theta terms has neither."""
    if exps.any():
        return noise_section(None, f"{THETA_NOISE}; {NO_W}")
    K = coefficients(F, p)
    peak = peak_to_peak(K)
    if (len(K) - 1) * p > FIR_STATES:        # the triangle inequality: ||sum_j K_j v_(k-j)||_2 <= sum_j ||K_j|| ||v||_2
        gain, why, extra = peak, None, {"certificate": {"method": "sum of the coefficients' 2-norms"}}
    else:
        gain, extra, why = certified(*fir_system(K))
    return noise_section(gain, "; ".join(([why] if why else []) + [NO_W]), error="gx_k - G x_(k-delay)",
                         peak_to_peak_y=peak, **extra)


def noise_checks(card_data: dict) -> list:
    """The re-check of the l2 gain a theta-free formula's card states, at its stored coefficients."""
    F, exps = (np.asarray(card_data["matrices"][k], dtype=float) for k in ("F", "Fexp"))
    noise = card_data.get("noise")
    if exps.any() or not isinstance(noise, dict) or "X" not in (noise.get("certificate") or {}):
        return []                                    # none, or the sum of norms (what the problem determines)
    return recheck(noise, *fir_system(coefficients(F, int(card_data["dims"]["p"]))))


def _schedule(plant, length: int, delay: int, uses_theta: bool) -> dict:
    return {"kind": "window", "dt": plant.dt, "length": length, "delay": delay, "theta": plant.s,
            "uses_theta": uses_theta, "step_policy": "error"}


def _bound(length: int, delay: int) -> str:
    return f"gx_k = G x_(k-{delay}) exactly from k = {length - 1} on (window of {length} outputs)"


def determined(problem, card_data, analysis: Analysis) -> dict:
    """What the card's problem determines: the inherent delay ``r``, the ``K`` of Algorithm 1 and the
    nilpotency class of its analysis, the plant's parts (the matrices the re-check simulates), ``C``,
    ``G``, the window ``K + max(r, 1) + 1`` and the delay ``max(r - 1, 0)`` (in the schedule and as
    reported), the bound and the formula's text."""
    plant = problem.plant
    mats = card_data["matrices"]
    F, exps = np.asarray(mats["F"], dtype=float), np.asarray(mats["Fexp"], dtype=float)
    r, K = analysis.data["inverse"].r, analysis.data["K"]
    length, delay = window_length(r, K), max(r - 1, 0)
    if F.ndim != 3 or F.shape[2] != length * plant.p:
        raise ValueError(f"matrices.F has shape {F.shape}: the window of r = {r}, K = {K} needs "
                         f"{length * plant.p} columns")
    found = {"r": r, "K": K, "nilpotency_class": analysis.data["t"]}
    return {"dt": plant.dt, "schedule": _schedule(plant, length, delay, bool(exps.any())), "window": length, **found,
            "delay": delay, "bound": _bound(length, delay),
            "formula": describe(F, exps, plant.p, length, delay), "decay_bound": None, "overshoot_bound": None,
            **_noise_figures(noise_of(F, exps, plant.p)), "matrices.C": plant.C, "matrices.G": problem.options.G,
            **{f"matrices.{k}": v for k, v in _parts(plant).items()}}


def _noise_figures(noise: dict) -> dict:
    """What a card's problem determines of its ``noise`` section: everything but the certificate's point
    (re-checked by :func:`verify`) and its rounding."""
    return {f"noise.{k}": v for k, v in noise.items() if k not in ("certificate", "initial_term")}


def design(problem, analysis: Analysis) -> DesignResult:
    """The window formula (Proposition 4), its arrays and its certificate."""
    plant, opts = problem.plant, problem.options
    inv, K = analysis.data["inverse"], analysis.data["K"]
    try:
        with work_limit():
            F, L, delay = formula(opts.G, inv, K, plant.p)
            if not F.is_constant(0.0):           # theta terms that are rounding of their products go
                F = F.without_rounding(formula(opts.G, inv, K, plant.p, sizes=True)[0], STRUCTURAL_RTOL)
    except TooLarge as exc:
        raise too_large(plant, exc, f"the window formula (Proposition 4, r = {inv.r}, K = {K})",
                        window_length(inv.r, K)) from None
    Fm, exps = to_arrays(F, L, plant.s)
    if exps.max(initial=0) > MAX_POWER:
        raise InfeasibleError(f"{NAME}: the formula has theta powers up to {int(exps.max())} "
                              f"(at most {MAX_POWER} supported)")
    matrices = {"F": Fm, "Fexp": exps, "G": opts.G, **_parts(plant), "C": plant.C}
    schedule = _schedule(plant, L, delay, bool(exps.any()))
    results_checks = checks(matrices, schedule)
    failed = [c for c in results_checks if not c.holds]
    if failed:
        raise InfeasibleError(f"{NAME} design of {problem.name}: the formula does not reproduce G x on simulated "
                              f"runs: {failed[0].name} = {failed[0].value:.3g} (needs <= {failed[0].bound:.3g})")
    cert = {"solver": "none", "status": "closed form (Proposition 4)", "parameters": {}, "lmi_margin": 0.0,
            "verify_fraction": 1.0, "lmi_eig_min": {},
            "checks": {c.name: c.to_data() for c in results_checks}, "verified": True, "solve_time_s": 0.0}
    results = {"r": inv.r, "K": K, "nilpotency_class": analysis.data["t"], "window": L, "delay": delay,
               "formula": describe(Fm, exps, plant.p, L, delay),
               "decay_bound": None, "overshoot_bound": None,
               "bound": _bound(L, delay), "noise": noise_of(Fm, exps, plant.p)}
    return DesignResult(0, plant.dt, schedule, matrices, cert, results, None, None)


def describe(F: np.ndarray, exps: np.ndarray, p: int, L: int, delay: int) -> str:
    """The formula as text, e.g. ``G x_k = 11 y_k + 2 y_k+1``."""
    def lag(pos):
        off = pos - (L - 1 - delay)
        return "k" if off == 0 else f"k{off:+d}"
    rows = []
    for row in range(F.shape[1]):
        terms = []
        for t in range(F.shape[0]):
            w = "·".join(f"θ{i + 1}_{lag(pos)}" + (f"^{int(e)}" if e > 1 else "")
                         for pos in range(L) for i in range(exps.shape[2]) for e in [exps[t, pos, i]] if e)
            for pos in range(L):
                for j in range(p):
                    c = F[t, row, pos * p + j]
                    if abs(c) > 1e-12:
                        y = f"y{j + 1}_{lag(pos)}" if p > 1 else f"y_{lag(pos)}"
                        terms.append(f"{c:.6g}" + (f"·{w}" if w else "") + f"·{y}")
        rows.append(f"(G x)_{row + 1} at k = " + (" + ".join(terms) if terms else "0"))
    return "; ".join(rows)
