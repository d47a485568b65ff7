"""The certificate of a design: the LMI re-check plus checks at the stored matrices.

A design is certified only when every check holds. Each check is a number, a bound and a
direction, evaluated with numpy on the matrices the runtime will use (not on the solver's
variables alone), and all of them go into the card.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .runtime.errors import InfeasibleError
from .lmi import LmiSolution
from .runtime.tolerances import IDENTITY_RTOL, LMI_MARGIN, VERIFY_FRACTION


@dataclass(frozen=True)
class Check:
    """``value <= bound`` (``at_most``) or ``value >= bound``."""

    name: str
    value: float
    bound: float
    at_most: bool = True

    @property
    def holds(self) -> bool:
        """Whether the check passes."""
        return bool(self.value <= self.bound if self.at_most else self.value >= self.bound)

    def to_data(self) -> dict:
        """JSON-ready form."""
        return {"value": self.value, "bound": self.bound, "relation": "<=" if self.at_most else ">=",
                "holds": self.holds}


def identity_check(name: str, residual: np.ndarray, scale: float, rtol: float = IDENTITY_RTOL) -> Check:
    """An identity that must hold exactly: ``||residual|| <= rtol * max(1, scale)``."""
    return Check(name, float(np.linalg.norm(residual, 2)) if residual.size else 0.0, rtol * max(1.0, scale))


def lyapunov_check(name: str, N: np.ndarray, X: np.ndarray, rho: float, X_prev: np.ndarray | None = None,
                   margin: float = LMI_MARGIN, verify_fraction: float = VERIFY_FRACTION) -> Check:
    """``rho^2 X_prev - N' X N > 0``: the decay ``||e_{k+1}||_X <= rho ||e_k||_{X_prev}`` at the
    stored ``N`` (``X_prev = X`` for a common Lyapunov matrix)."""
    X_prev = X if X_prev is None else X_prev
    Q = rho * rho * X_prev - N.T @ X @ N
    return Check(name, float(np.linalg.eigvalsh(0.5 * (Q + Q.T))[0]), verify_fraction * margin, at_most=False)


def decay_check(rho: float) -> Check:
    """``rho < 1``: a decay bound of 1 or more certifies no convergence, whatever else holds."""
    return Check("decay bound < 1", float(rho), 1.0 - 2.0 ** -52)


def positive_check(name: str, X: np.ndarray, margin: float = LMI_MARGIN,
                   verify_fraction: float = VERIFY_FRACTION) -> Check:
    """``X > 0`` by its smallest eigenvalue."""
    return Check(name, float(np.linalg.eigvalsh(0.5 * (X + X.T))[0]), verify_fraction * margin, at_most=False)


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
                              + "; ".join(f"{c.name} = {c.value:.3g} (needs {'<=' if c.at_most else '>='} "
                                          f"{c.bound:.3g})" for c in failed))
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
