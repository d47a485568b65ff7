"""Matrices polynomial in scheduling variables, with exact coefficient arithmetic.

An LPV plant's matrices are affine in the parameter, ``A(theta) = A_0 + sum_i theta^(i) A_i``;
products over a window of steps (``C A(theta_{k+1}) A(theta_k)``) are polynomial in the window's
values. A :class:`PolyMatrix` holds such a matrix as its coefficients, one per monomial, so that
products and sums are computed exactly (the coefficients are those of the symbolic expansion,
in double precision), never fitted from samples.

A monomial is a sorted tuple of ``(variable, power)`` pairs; a variable is any hashable (the
families use ``(lag, component)``: ``theta^(component)`` at step ``k + lag``). ``()`` is the
constant monomial.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
        return out

    def __neg__(self) -> "PolyMatrix":
        return PolyMatrix(self.shape, {m: -c for m, c in self.coeffs.items()})

    def __sub__(self, other: "PolyMatrix") -> "PolyMatrix":
        return self + (-other)

    def __matmul__(self, other) -> "PolyMatrix":
        if not isinstance(other, PolyMatrix):
            other = PolyMatrix.constant(other)
        out: dict = {}
        for ma, a in self.coeffs.items():
            for mb, b in other.coeffs.items():
                m = _times(ma, mb)
                prod = a @ b
                out[m] = out[m] + prod if m in out else prod
        return PolyMatrix((self.shape[0], other.shape[1]), out)

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
    return PolyMatrix(tuple(shape), out)


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
