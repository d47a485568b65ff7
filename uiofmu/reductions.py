"""Changes of coordinates of an LMI design as reductions: ``apply`` and ``invert``.

A design may solve its LMIs in other coordinates than the plant's (balanced states, the kernel of
``C``, coordinates centred on a refused point) and map the point the solver returns back. Each such
change is a :class:`Reduction`: :meth:`Reduction.apply` turns the problem it accepts into the reduced
one and the data its inverse needs, :meth:`Reduction.invert` maps a point of the reduced problem to a
point of the original one with that data. A certificate of the reduced LMIs maps back to a certificate
of the original ones.

How a variable maps back under a congruence is declared with the variable, as the last element of
its entry in :attr:`uiofmu.lmi.LmiSystem.variables` (:func:`symmetric`, :func:`matrix`,
:func:`scalar`), never guessed from its name:

* :data:`LYAPUNOV`: a Lyapunov matrix, by congruence ``X = S' Xr S``;
* :data:`PRODUCT`: a product ``X K`` of a Lyapunov matrix and a gain, from the left ``W = S' Wr``
  (its gain ``K = X^-1 W`` maps by ``S^-1``, the change of the states, by itself);
* :data:`UPPER_BOUND`: a scalar ``mu`` with ``X <= mu I``, by the largest eigenvalue of ``S' S`` (so that
  the bound holds for the mapped matrices);
* :data:`UNCHANGED`: the same number in both coordinates (a margin, ``gamma``, the slack of a cap).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

#: A Lyapunov matrix: maps back by congruence, ``X = S' Xr S``.
LYAPUNOV = "lyapunov"
#: A product ``X K`` of a Lyapunov matrix and a gain: maps back from the left, ``W = S' Wr``.
PRODUCT = "product"
#: An upper bound ``mu`` of Lyapunov matrices (``X <= mu I``): maps back by ``eig_max(S' S)``.
UPPER_BOUND = "upper bound"
#: The same value in both coordinates.
UNCHANGED = "unchanged"

#: Every way a variable maps back.
ROLES = (LYAPUNOV, PRODUCT, UPPER_BOUND, UNCHANGED)


def symmetric(n: int, role: str = LYAPUNOV) -> tuple:
    """The declaration of a symmetric ``n x n`` variable of :class:`uiofmu.lmi.LmiSystem` and how it maps back."""
    return ("symmetric", n, _role_checked(role))


def matrix(shape: tuple, role: str = PRODUCT) -> tuple:
    """The declaration of a ``rows x cols`` matrix variable and how it maps back."""
    return ("matrix", tuple(shape), _role_checked(role))


def scalar(role: str = UNCHANGED) -> tuple:
    """The declaration of a scalar variable and how it maps back."""
    return ("scalar", (1, 1), _role_checked(role))


def _role_checked(role: str) -> str:
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r} of an LMI variable; one of {', '.join(ROLES)}")
    return role


def role_of(spec: tuple) -> str:
    """How the variable declared by ``spec`` maps back: its declared role; :data:`UNCHANGED` for a
    scalar that declares none.

    Raises
    ------
    ValueError
        For a matrix variable that declares no role (a congruence cannot guess it).
    """
    if len(spec) > 2:
        return _role_checked(spec[2])
    if spec[0] == "scalar":
        return UNCHANGED
    raise ValueError(f"an LMI variable {spec!r} declares no role: declare it with uiofmu.reductions.symmetric "
                     "or matrix")


def roles(variables: dict) -> dict:
    """``name -> role`` of every variable of an :attr:`uiofmu.lmi.LmiSystem.variables` dict."""
    return {name: role_of(spec) for name, spec in variables.items()}


class Reduction:
    """A change of an LMI problem into another whose certificates map back to the first's.

    Subclasses say which problems :meth:`apply` accepts.
    """

    def apply(self, problem) -> tuple:
        """``(reduced problem, inverse_data)``: the reduced problem, and what :meth:`invert` needs."""
        raise NotImplementedError

    def invert(self, values: dict, inverse_data) -> dict:
        """A point of the reduced problem (``name -> array``) as a point of the original one."""
        raise NotImplementedError


@dataclass(frozen=True)
class DiagonalCongruence:
    """The congruence of a diagonal change of the states ``x = diag(d) xr``: ``S = diag(d)^-1``.

    Divides by ``d`` rather than multiplying by its inverse, so that a ``d`` of powers of two maps
    exactly.
    """

    d: np.ndarray

    def lyapunov(self, X) -> np.ndarray:
        """``S' X S``."""
        return np.asarray(X, dtype=float) / np.outer(self.d, self.d)

    def product(self, W) -> np.ndarray:
        """``S' W``."""
        return np.asarray(W, dtype=float) / self.d[:, None]

    def bound(self, mu) -> np.ndarray:
        """``mu eig_max(S' S)``."""
        return np.asarray(float(mu) / float(np.min(self.d)) ** 2)

    def forward(self) -> "DiagonalCongruence":
        """The congruence of the opposite change of the states."""
        return DiagonalCongruence(1.0 / self.d)


@dataclass(frozen=True)
class SymmetricCongruence:
    """The congruence ``S = R`` of a symmetric positive definite ``R`` (``R' = R``), with ``largest``
    the largest eigenvalue of ``R R`` and ``inverse`` ``R^-1``."""

    R: np.ndarray
    inverse: np.ndarray
    largest: float

    def lyapunov(self, X) -> np.ndarray:
        """``R X R``."""
        return self.R @ X @ self.R

    def product(self, W) -> np.ndarray:
        """``R W``."""
        return self.R @ W

    def bound(self, mu) -> np.ndarray:
        """``mu eig_max(R R)``."""
        return np.asarray(float(mu) * self.largest)

    def forward(self) -> "SymmetricCongruence":
        """The congruence of the opposite change of coordinates."""
        w = np.linalg.eigvalsh(self.inverse @ self.inverse)
        return SymmetricCongruence(self.inverse, self.R, float(w[-1]))


@dataclass(frozen=True)
class CongruenceData:
    """The inverse data of a congruence: the congruence and the role of each variable (:func:`roles`)."""

    congruence: object
    roles: dict


def congruent(values: dict, data: CongruenceData) -> dict:
    """``values`` mapped by ``data.congruence``, each variable as its role says."""
    c = data.congruence
    maps = {LYAPUNOV: c.lyapunov, PRODUCT: c.product, UPPER_BOUND: c.bound}
    return {k: maps[data.roles[k]](x) if data.roles[k] in maps else x for k, x in values.items()}


def reduced_values(values: dict, data: CongruenceData) -> dict:
    """A point of the original problem in the reduced coordinates (what :func:`congruent` maps back);
    a bound is mapped to one that holds there."""
    return congruent(values, CongruenceData(data.congruence.forward(), data.roles))


def mean_root(values: dict, variable_roles: dict) -> SymmetricCongruence | None:
    """``R = P0^(1/2)`` of the mean ``P0`` of a point's Lyapunov matrices (symmetrised), scaled to
    ``eig_min(P0) = 1`` (eigenvalues below ``1e-12`` of the largest raised to it); None when the
    mean is not positive definite."""
    names = [k for k, r in variable_roles.items() if r == LYAPUNOV]
    P0 = sum(0.5 * (np.asarray(values[k]) + np.asarray(values[k]).T) for k in names) / len(names)
    w, V = np.linalg.eigh(P0)
    if not np.all(np.isfinite(w)) or w[-1] <= 0:
        return None
    w = np.maximum(w, 1e-12 * w[-1])
    w = w / w[0]
    return SymmetricCongruence((V * np.sqrt(w)) @ V.T, (V / np.sqrt(w)) @ V.T, float(w[-1]))


@dataclass(frozen=True)
class Recentring(Reduction):
    """The same LMIs in the coordinates ``xi = P0^(1/2) e`` of a point's mean Lyapunov matrix ``P0``
    (:func:`mean_root`), where the Lyapunov matrices near that point are near the identity, so that
    the solver's relative tolerance resolves all of their directions.

    Parameters
    ----------
    rebuild : callable
        ``rebuild(R, Ri) -> LmiSystem``: the LMIs with every map ``F`` of the error replaced by
        ``R F Ri`` (``Ri = R^-1``), without a recentring of their own.
    variables : dict
        The original system's variable declarations (their roles say how each maps back).
    """

    rebuild: Callable
    variables: dict

    def apply(self, problem: dict) -> tuple | None:
        """``(system, inverse_data)`` in the coordinates centred on the point ``problem`` (a dict of
        values); None when its mean Lyapunov matrix is not positive definite. Since ``P0 >= I``, a
        point of the new coordinates maps to one with at least the margins it had there."""
        variable_roles = roles(self.variables)
        root = mean_root(problem, variable_roles)
        if root is None:
            return None
        return self.rebuild(root.R, root.inverse), CongruenceData(root, variable_roles)

    def invert(self, values: dict, inverse_data: CongruenceData) -> dict:
        """``P = R Pt R`` for a Lyapunov matrix, ``mu eig_max(R R)`` for a bound."""
        return congruent(values, inverse_data)

    def frame(self, values: dict) -> tuple | None:
        """``(system, back)`` for :attr:`uiofmu.lmi.LmiSystem.recentre`."""
        applied = self.apply(values)
        if applied is None:
            return None
        system, data = applied
        return system, lambda v: self.invert(v, data)


__all__ = [
    "CongruenceData", "DiagonalCongruence", "LYAPUNOV", "PRODUCT", "ROLES", "Recentring", "Reduction",
    "SymmetricCongruence", "UNCHANGED", "UPPER_BOUND", "congruent", "matrix", "mean_root", "reduced_values",
    "role_of", "roles", "scalar", "symmetric",
]
