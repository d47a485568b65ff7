"""Check and design: the family-independent entry points and the card assembly."""

from __future__ import annotations

import platform
import time

from . import __version__
from .card import FORMAT, VERSION, Card, card_from_data, to_lists
from .existence import Existence
from .families import family_module
from .problem import Problem


def check(problem: Problem) -> Existence:
    """Existence analysis of the problem's family (``uiofmu check``)."""
    return family_module(problem.family).check(problem)


def design(problem: Problem) -> Card:
    """Solve the family's design, verify its certificate, return the card (``uiofmu design``).

    Raises
    ------
    NoObserverError
        When the existence conditions fail.
    InfeasibleError
        When the LMIs are infeasible or the certificate does not verify.
    """
    return family_module(problem.family).design(problem)


def verify(card: Card) -> list:
    """Re-check a design card's certificate from its stored matrices, without any solver.

    Returns
    -------
    list of Check
        Every check with its value and bound; the card is certified when all hold.
    """
    return family_module(card.family).verify(card)


def assemble_card(problem: Problem, *, nz: int, dt: float | None, schedule: dict, matrices: dict,
                  certificate: dict, xhat0, results: dict, existence: Existence, lmi, started: float) -> Card:
    """The design card of a finished design (shared by every family).

    Parameters
    ----------
    problem : Problem
    nz : int
        Dimension of the observer's internal state ``z``.
    dt : float or None
        Design period.
    schedule : dict
        The runtime schedule entry (``kind`` and its data).
    matrices : dict
        Runtime matrices (see :data:`uiofmu.card.RUNTIME_SHAPES`) plus family matrices
        users look at.
    certificate : dict
        From :func:`uiofmu.certificate.certificate`.
    xhat0 : array_like
        Initial estimate.
    results : dict
        Family results at top level (``invariant_zeros``, ``decay_bound``, ...).
    existence : Existence
        The existence analysis the design passed.
    lmi : LmiSystem
        The design's LMI system (its assembly time, solves and solver time go to ``timing``).
    started : float
        ``time.perf_counter()`` when the design started (``timing.total_s`` ends here).

    Returns
    -------
    Card
    """
    plant = problem.plant
    data = {
        "format": FORMAT,
        "version": VERSION,
        "family": problem.family,
        "name": problem.name,
        "generator": f"uiofmu {__version__} (python {platform.python_version()})",
        "dims": {"n": plant.n, "m": plant.m, "p": plant.p, "q": plant.q, "nz": nz},
        "time": plant.time,
        "dt": dt,
        "schedule": schedule,
        "initial": {"xhat0": to_lists(xhat0)},
        **to_lists(results),
        "existence": to_lists(existence.to_data()),
        "matrices": to_lists(matrices),
        "certificate": to_lists(certificate),
        "problem": problem.data,
        "timing": {"total_s": time.perf_counter() - started, "lmi_assembly_s": lmi.assembly_time,
                   "solver_s": lmi.solver_time, "solves": lmi.solves, "backend": lmi.backend},
    }
    return card_from_data(data)
