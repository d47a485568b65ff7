"""Existence reports: the list of conditions a family checks, each with its numbers."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .runtime.errors import NoObserverError


def complex_list(values) -> list:
    """Complex numbers as JSON-friendly ``[re, im]`` pairs."""
    return [[float(np.real(v)), float(np.imag(v))] for v in np.asarray(values).ravel()]


def from_pairs(pairs) -> np.ndarray:
    """``[re, im]`` pairs (:func:`complex_list`) back as complex numbers."""
    arr = np.asarray(pairs, dtype=float).reshape(-1, 2)
    return arr[:, 0] + 1j * arr[:, 1]


#: Parts of the numbers of a message below this, relative to the largest modulus (or 1), print as 0: an
#: eigenvalue at zero comes out of the arithmetic as -2.4e-15 under one BLAS kernel and 4.8e-16 under another.
ROUNDING_ZERO = 1e-12


def format_complex(values) -> str:
    """Complex numbers for a message: ``0.99, 0.5±0.2j`` (conjugates merged; parts at the rounding level,
    :data:`ROUNDING_ZERO`, as 0)."""
    values = np.asarray(values, dtype=complex).ravel()
    tiny = ROUNDING_ZERO * max(1.0, float(np.abs(values).max(initial=0.0)))
    out = []
    for v in values:
        re = v.real if abs(v.real) >= tiny else 0.0
        if abs(v.imag) < tiny:
            out.append(f"{re:.6g}")
        elif v.imag > 0:
            out.append(f"{re:.6g}±{v.imag:.6g}j")
    return ", ".join(out) if out else "none"


@dataclass(frozen=True)
class Condition:
    """One checked condition.

    Attributes
    ----------
    name : str
        Short identifier (``rank(CE) = rank(E)``).
    holds : bool
    required : bool
        Whether the observer needs it (informational conditions are not required).
    message : str
        One sentence with the numbers, e.g. ``rank(CE) = 1 < rank(E) = 2``.
    values : dict
        The numbers, JSON-ready.
    solver : bool
        Whether deciding it took a solve (an LMI condition): ``analyse(problem, solver=False)``
        leaves such conditions out, and :func:`uiofmu.verify`, which runs no solver, keeps the card's
        as the solver's record.
    hint : str
        For a failing condition, what would make it hold when that can be computed cheaply (an extra
        measurement, another sampling period, a slower decay, more delays), checked by recomputing the
        condition with the change applied; empty otherwise.
    """

    name: str
    holds: bool
    required: bool
    message: str
    values: dict = field(default_factory=dict)
    solver: bool = False
    hint: str = ""

    def to_data(self) -> dict:
        """JSON-ready form (``hint`` only when there is one)."""
        return {"name": self.name, "holds": bool(self.holds), "required": self.required,
                "message": self.message, "values": self.values, **({"solver": True} if self.solver else {}),
                **({"hint": self.hint} if self.hint else {})}

    def explained(self) -> str:
        """The message, and the hint when there is one (``...; would help: ...``)."""
        return f"{self.message}; would help: {self.hint}" if self.hint else self.message


@dataclass(frozen=True)
class Existence:
    """The existence analysis of one family on one problem."""

    family: str
    conditions: tuple[Condition, ...]

    @property
    def exists(self) -> bool:
        """True when every required condition holds."""
        return all(c.holds for c in self.conditions if c.required)

    @property
    def failures(self) -> list[Condition]:
        """The required conditions that fail."""
        return [c for c in self.conditions if c.required and not c.holds]

    def to_data(self) -> dict:
        """JSON-ready form (``uiofmu check --json``)."""
        return {"family": self.family, "exists": self.exists,
                "conditions": [c.to_data() for c in self.conditions]}

    def require(self) -> "Existence":
        """Return self, or raise :class:`NoObserverError` naming the failed conditions."""
        if not self.exists:
            raise NoObserverError(f"no {self.family} observer exists: "
                                  + "; ".join(c.explained() for c in self.failures))
        return self

    def holds(self, name: str) -> bool:
        """Whether the named condition holds."""
        for c in self.conditions:
            if c.name == name:
                return bool(c.holds)
        raise KeyError(name)

    def value(self, name: str, key: str):
        """A value of a named condition."""
        for c in self.conditions:
            if c.name == name:
                return c.values[key]
        raise KeyError(name)
