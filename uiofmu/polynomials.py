"""Matrices polynomial in scheduling variables, with exact coefficient arithmetic.

An LPV plant's matrices are affine in the parameter, ``A(theta) = A_0 + sum_i theta^(i) A_i``;
products over a window of steps (``C A(theta_{k+1}) A(theta_k)``) are polynomial in the window's
values. A :class:`PolyMatrix` holds such a matrix as its coefficients, one per monomial, so that
products and sums are computed exactly (the coefficients are those of the symbolic expansion,
in double precision), never fitted from samples.

A monomial is a sorted tuple of ``(variable, power)`` pairs; a variable is any hashable (the
families use ``(lag, component)``: ``theta^(component)`` at step ``k + lag``). ``()`` is the
constant monomial.

The number of monomials grows combinatorially with the products (a product of ``L`` affine factors
in ``s`` variables each has up to ``(s + 1)^L`` of them), so the arithmetic is bounded by what it
costs: every product is charged its coefficient products before it starts (:data:`MAX_WORK`), no
matrix may hold more than :data:`MAX_BYTES`, and the matrices computed inside one
:func:`work_limit` no more than :data:`MAX_ALLOCATED` together; past any of them,
:class:`TooLarge` is raised with the numbers, for the caller to turn into a message about its problem.
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field

import numpy as np

#: Cost of one coefficient product besides its multiply-adds, in multiply-adds: the monomial key,
#: the dict update and numpy's call overhead take about 3 µs, what ~4000 multiply-adds of a small
#: matrix product take (measured: 3-4 µs per pair of 8x8 or 16x16 coefficients).
PAIR_OVERHEAD = 4000
#: Most work (multiply-adds plus :data:`PAIR_OVERHEAD` per coefficient product) inside one
#: :func:`work_limit` (one analysis, one design): at about 1e9 per second, about 1 s (some 250 000
#: coefficient products of small matrices). The seed 003 examples' analyses take 9 and 5 coefficient
#: products of 3x3 matrices (3.6e4 and 2.0e4), their formulas 4 and 13 (1.6e4, 5.2e4): 10^4 times less.
MAX_WORK = 1_000_000_000
#: Bytes of one monomial besides its coefficients: the key (a tuple of ``(variable, power)``
#: tuples), the dict slot and the array header.
TERM_BYTES = 400
#: Most bytes one polynomial matrix may hold (8 per coefficient entry plus :data:`TERM_BYTES` per
#: monomial): 8 MB, e.g. 13 000 monomials of 5x5 coefficients or 3 000 of 16x16. What a family does
#: with the result (a subspace iteration over every coefficient, the card's lists of them) is then
#: bounded too. The seed 003 examples' largest holds 3 monomials of 3x3 coefficients (1.4 kB; the
#: limit is 16 949 of them).
MAX_BYTES = 8_000_000
#: Most bytes of all the matrices computed inside one :func:`work_limit` (they may be kept for
#: reuse): the resident memory of an analysis stays within a few hundred MB. The seed 003 examples
#: compute at most 10 kB.
MAX_ALLOCATED = 200_000_000


class TooLarge(ArithmeticError):
    """A polynomial computation would pass :data:`MAX_WORK`, :data:`MAX_BYTES` or :data:`MAX_ALLOCATED`.

    Attributes
    ----------
    terms : int
        The monomials of the operand or result that passed the limit.
    """

    def __init__(self, message: str, terms: int):
        super().__init__(message)
        self.terms = terms


@dataclass
class Work:
    """The work charged inside one :func:`work_limit`.

    Attributes
    ----------
    limit : int
        :data:`MAX_WORK` unless told otherwise.
    used : int
        Multiply-adds plus :data:`PAIR_OVERHEAD` per coefficient product so far.
    products : int
        Coefficient products so far.
    terms : int
        The most monomials of a matrix computed so far.
    allocated : int
        Bytes of the matrices computed so far (:func:`size`), at most :data:`MAX_ALLOCATED`.
    """

    limit: int = MAX_WORK
    used: int = 0
    products: int = 0
    terms: int = 0
    allocated: int = 0


_WORK: ContextVar = ContextVar("uiofmu_polynomial_work", default=None)


@contextmanager
def work_limit(limit: int | None = None):
    """Charge every product of :class:`PolyMatrix` inside the block to one :class:`Work` (yielded),
    of at most ``limit`` (default :data:`MAX_WORK`); outside any block, each product is bounded on its
    own by :data:`MAX_WORK`."""
    work = Work(MAX_WORK if limit is None else limit)
    token = _WORK.set(work)
    try:
        yield work
    finally:
        _WORK.reset(token)


def _charge(left: "PolyMatrix", right: "PolyMatrix") -> None:
    """Charge ``left @ right`` before it starts; :class:`TooLarge` if it would pass the limit."""
    work = _WORK.get() or Work(MAX_WORK)
    pairs = len(left.coeffs) * len(right.coeffs)
    cost = pairs * (left.shape[0] * left.shape[1] * right.shape[1] + PAIR_OVERHEAD)
    if work.used + cost > work.limit:
        raise TooLarge(f"a product of matrices of {len(left.coeffs)} and {len(right.coeffs)} monomials "
                       f"({left.shape[0]}x{left.shape[1]} and {right.shape[0]}x{right.shape[1]}) needs {pairs} "
                       f"coefficient products, which with the {work.products} taken so far passes the work limit "
                       f"of {work.limit:.3g} multiply-adds (about {work.limit / 1e9:.2g} s)",
                       max(len(left.coeffs), len(right.coeffs)))
    work.used += cost
    work.products += pairs


def size(shape: tuple, terms: int) -> int:
    """Bytes of a matrix of ``shape`` with ``terms`` monomials (coefficients and :data:`TERM_BYTES`)."""
    return terms * (8 * shape[0] * shape[1] + TERM_BYTES)


def max_terms(shape: tuple) -> int:
    """The most monomials a matrix of ``shape`` may hold within :data:`MAX_BYTES`."""
    return MAX_BYTES // size(shape, 1)


def _held(P: "PolyMatrix") -> "PolyMatrix":
    """``P``, after checking it within :data:`MAX_BYTES` and, inside a :func:`work_limit`, the
    bytes computed so far within :data:`MAX_ALLOCATED`."""
    terms = len(P.coeffs)
    if terms > max_terms(P.shape):
        raise _too_many(P.shape, terms)
    work = _WORK.get()
    if work is not None:
        work.terms = max(work.terms, terms)
        work.allocated += size(P.shape, terms)
        if work.allocated > MAX_ALLOCATED:
            raise TooLarge(f"the matrices computed so far hold {work.allocated / 1e6:.0f} MB (the last one "
                           f"{P.shape[0]}x{P.shape[1]} with {terms} monomials), more than the "
                           f"{MAX_ALLOCATED / 1e6:.0f} MB allowed", terms)
    return P


def _too_many(shape: tuple, terms: int) -> TooLarge:
    return TooLarge(f"a {shape[0]}x{shape[1]} matrix reaches {terms} monomials, more than the "
                    f"{max_terms(shape)} that fit in {MAX_BYTES / 1e6:.0f} MB", terms)


def _times(a: tuple, b: tuple) -> tuple:
    powers = dict(a)
    for var, p in b:
        powers[var] = powers.get(var, 0) + p
    return tuple(sorted(powers.items()))


@dataclass
class PolyMatrix:
    """A matrix polynomial in variables: ``sum_m coeffs[m] * monomial_m``.

    Attributes
    ----------
    shape : tuple of int
    coeffs : dict
        ``monomial -> (rows, cols) array``; absent monomials are zero.
    """

    shape: tuple
    coeffs: dict = field(default_factory=dict)

    @classmethod
    def constant(cls, M) -> "PolyMatrix":
        """A matrix that depends on no variable."""
        M = np.asarray(M, dtype=float)
        return cls(M.shape, {(): M.copy()})

    @classmethod
    def affine(cls, M0, parts: dict) -> "PolyMatrix":
        """``M0 + sum_v v * parts[v]`` (``parts``: variable -> matrix)."""
        out = cls.constant(M0)
        for var, M in parts.items():
            M = np.asarray(M, dtype=float)
            if np.any(M):
                out.coeffs[((var, 1),)] = M.copy()
        return out

    def __add__(self, other: "PolyMatrix") -> "PolyMatrix":
        out = PolyMatrix(self.shape, {m: c.copy() for m, c in self.coeffs.items()})
        for m, c in other.coeffs.items():
            out.coeffs[m] = out.coeffs[m] + c if m in out.coeffs else c.copy()
        return _held(out)

    def __neg__(self) -> "PolyMatrix":
        return _held(PolyMatrix(self.shape, {m: -c for m, c in self.coeffs.items()}))

    def __sub__(self, other: "PolyMatrix") -> "PolyMatrix":
        return self + (-other)

    def __matmul__(self, other) -> "PolyMatrix":
        """The product, charged to the current :func:`work_limit` before it starts; exactly zero
        coefficient products are left out (they add nothing).

        Raises
        ------
        TooLarge
            When the product would pass :data:`MAX_WORK`, or its result :data:`MAX_BYTES`.
        """
        if not isinstance(other, PolyMatrix):
            other = PolyMatrix.constant(other)
        _charge(self, other)
        shape = (self.shape[0], other.shape[1])
        most = max_terms(shape)
        out: dict = {}
        for ma, a in self.coeffs.items():
            for mb, b in other.coeffs.items():
                prod = a @ b
                if not prod.any():
                    continue
                m = _times(ma, mb)
                if m in out:
                    out[m] = out[m] + prod
                elif len(out) < most:
                    out[m] = prod
                else:
                    raise _too_many(shape, len(out) + 1)
        return _held(PolyMatrix(shape, out))

    def __rmatmul__(self, other) -> "PolyMatrix":
        return PolyMatrix.constant(other) @ self

    def rows(self, sl) -> "PolyMatrix":
        """The rows ``sl`` (a slice or index array)."""
        coeffs = {m: c[sl] for m, c in self.coeffs.items()}
        n = next(iter(coeffs.values())).shape[0] if coeffs else len(range(self.shape[0])[sl])
        return PolyMatrix((n, self.shape[1]), coeffs)

    def cols(self, sl) -> "PolyMatrix":
        """The columns ``sl``."""
        coeffs = {m: c[:, sl] for m, c in self.coeffs.items()}
        n = next(iter(coeffs.values())).shape[1] if coeffs else len(range(self.shape[1])[sl])
        return PolyMatrix((self.shape[0], n), coeffs)

    def pruned(self, tol: float = 0.0) -> "PolyMatrix":
        """Without the monomials whose coefficient is at most ``tol`` relative to the largest one."""
        big = max((float(np.abs(c).max()) for c in self.coeffs.values() if c.size), default=0.0)
        keep = {m: c for m, c in self.coeffs.items() if c.size and float(np.abs(c).max()) > tol * big}
        return PolyMatrix(self.shape, keep)

    def without_rounding(self, magnitude: "PolyMatrix", rtol: float) -> "PolyMatrix":
        """Without the entries that are rounding of the products they sum: ``|c| <= rtol * m`` entrywise,
        ``m`` the coefficient of the same monomial in ``magnitude`` (the same computation on the absolute
        values of every factor, which bounds the size of the terms each entry adds up). A monomial whose
        entries are all rounding is left out; an entry that is exactly zero in exact arithmetic is so to
        rounding of its terms' size, whatever the scale of the rest.

        Parameters
        ----------
        magnitude : PolyMatrix
            The same polynomial computed from absolute values.
        rtol : float

        Returns
        -------
        PolyMatrix
        """
        keep = {}
        for m, c in self.coeffs.items():
            bound = magnitude.coeffs.get(m, np.zeros(c.shape))
            cleaned = np.where(np.abs(c) <= rtol * bound, 0.0, c)
            if cleaned.any() or m == ():
                keep[m] = cleaned
        return PolyMatrix(self.shape, keep)

    @property
    def variables(self) -> set:
        """The variables that appear."""
        return {var for m in self.coeffs for var, _ in m}

    def is_constant(self, tol: float = 0.0) -> bool:
        """Whether every non-constant coefficient is zero (up to ``tol`` relative)."""
        return all(m == () for m in self.pruned(tol).coeffs)

    def __call__(self, values: dict) -> np.ndarray:
        """The matrix at ``values`` (variable -> number)."""
        out = np.zeros(self.shape)
        for m, c in self.coeffs.items():
            w = 1.0
            for var, p in m:
                w *= values[var] ** p
            out += w * c
        return out


def _concat(blocks: list, axis: int) -> PolyMatrix:
    """Blocks joined along ``axis``, monomial by monomial (a block without a monomial contributes zeros).

    Parameters
    ----------
    blocks : list of PolyMatrix
        Equal in size along the other axis.
    axis : int
        0: on top of each other; 1: side by side.

    Returns
    -------
    PolyMatrix
    """
    shape = list(blocks[0].shape)
    shape[axis] = sum(b.shape[axis] for b in blocks)
    terms = len(set().union(*(b.coeffs for b in blocks)))
    if terms > max_terms(shape):            # before allocating them
        raise _too_many(shape, terms)
    out: dict = {}
    start = 0
    for b in blocks:
        part = [slice(None), slice(None)]
        part[axis] = slice(start, start + b.shape[axis])
        for m, c in b.coeffs.items():
            if m not in out:
                out[m] = np.zeros(shape)
            out[m][tuple(part)] = c
        start += b.shape[axis]
    return _held(PolyMatrix(tuple(shape), out))


def stack(blocks: list) -> PolyMatrix:
    """Block rows on top of each other (equal numbers of columns)."""
    return _concat(blocks, 0)


def hstack(blocks: list) -> PolyMatrix:
    """Blocks side by side (equal numbers of rows)."""
    return _concat(blocks, 1)


def shifted(P: PolyMatrix, lag: int) -> PolyMatrix:
    """``P`` with every variable ``(l, i)`` moved to ``(l + lag, i)``."""
    coeffs = {tuple(sorted(((v[0] + lag, v[1]), p) for v, p in m)): c for m, c in P.coeffs.items()}
    return PolyMatrix(P.shape, coeffs)
