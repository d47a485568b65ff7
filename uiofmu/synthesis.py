"""Check and design: the family-independent entry points and the card assembly."""

from __future__ import annotations

import contextlib
import math
import platform
import time

import numpy as np

from . import __version__
from .runtime.card import FORMAT, VERSION, Card, check_card, declared_ports, to_lists
from .runtime.errors import CardError, InfeasibleError, NumericalError, ProblemError
from .existence import Existence
from .families import DesignResult, available_family
from .consistency import DETERMINED, consistency_checks, existence_checks, plant_record, plant_scale
from .gains import cap_check
from .problem import Problem, problem_from_data
from .runtime.registry import FAMILIES
from .runtime.tolerances import LMI_MARGIN
from .threads import single_blas_thread


@contextlib.contextmanager
def _numerics(problem: Problem, stage: str):
    """Linear algebra that fails on the problem's numbers is a problem the user can fix."""
    try:
        yield
    except (np.linalg.LinAlgError, OverflowError, FloatingPointError) as exc:
        A = problem.plant.A
        raise NumericalError(f"{problem.name}: the {stage} failed numerically ({type(exc).__name__}: {exc}); "
                             f"the plant's entries range up to {float(np.abs(A).max()):.3g} in A: rescale the "
                             "units, or choose a smaller sampling period") from None


@single_blas_thread(with_scipy=True)
def check(problem: Problem) -> Existence:
    """Existence analysis of the problem's family (``uiofmu check``)."""
    with _numerics(problem, "existence analysis"):
        return available_family(problem.family).analyse(problem).existence


@single_blas_thread(with_scipy=True)
def design(problem: Problem) -> Card:
    """Analyse, solve the family's design, verify its certificate, return the card (``uiofmu design``).

    The skeleton every family shares: the existence analysis must hold, the family designs
    (:class:`~uiofmu.families.DesignResult`), a failure is completed with what makes the
    problem hard, and the card is assembled and timed here.

    Raises
    ------
    NoObserverError
        When the existence conditions fail.
    InfeasibleError
        When the LMIs are infeasible or the certificate does not verify.
    """
    family = available_family(problem.family)
    started = time.perf_counter()
    with _numerics(problem, "design"):
        analysis = family.analyse(problem)
        analysis.existence.require()
        try:
            result = family.design(problem, analysis)
        except InfeasibleError as exc:
            notes = _tight_spots(analysis.existence.conditions)
            cap = problem.options.gain_cap
            if cap is not None and not FAMILIES[problem.family].closed_form and "gain_cap" not in str(exc):
                notes.append(f"the LMIs bound every gain by observer.gain_cap = {cap:g}: a larger cap, or a slower "
                             "decay, leaves them more room")
            if not notes:
                raise
            raise type(exc)(f"{exc}. " + ". ".join(n[0].upper() + n[1:] for n in notes)) from None
    card = assemble_card(problem, result, analysis.existence, started)
    capped = _cap_checks(card.data, problem)
    if capped and not capped[0].holds:
        method = card.data.get("design_method") or "closed-form"
        why = ("the LMI point's gain misses the cap by more than its rounding: a slightly larger gain_cap or a "
               "slower decay leaves the LMIs room" if method.startswith("lmi") else
               f"the {method} design's gains follow from a formula, which no cap lowers: raise gain_cap")
        raise InfeasibleError(f"{problem.family} design of {problem.name}: its largest gain (2-norm) "
                              f"{capped[0].value:.6g} exceeds observer.gain_cap = {problem.options.gain_cap:g}; {why}")
    return card


def _cap_checks(card_data: dict, problem: Problem) -> list:
    """``max ||K||_2 <= observer.gain_cap`` at the card's gains, when the problem gives a cap."""
    cap = problem.options.gain_cap
    return [] if cap is None else [cap_check(card_data, cap)]


#: A decay limit this close to its bound leaves the LMIs' margins almost no room.
TIGHT = 1e-3


def _tight_spots(conditions) -> list:
    """What makes a design hard, from the existence report: weakly observable modes, and a
    fixed mode or sampled zero so close to the unit circle that the decay has little room."""
    notes = [c.message for c in conditions if c.name == "well observable modes" and not c.holds]
    for c in conditions:
        room = c.values.get("alpha_limit", 1.0 - c.values.get("largest_fixed_modulus", 0.0) ** 2)
        if c.holds and isinstance(room, float) and 0 < room < TIGHT:
            notes.append(f"{c.message}: that leaves the design a room of {room:.3g} against LMI margins of "
                         f"{LMI_MARGIN:g}")
    return notes


@single_blas_thread(with_scipy=True)
def verify(card: Card) -> list:
    """Re-check a design card's certificate from its stored matrices, without any solver.

    First what the card's problem determines: the plant's record, the existence analysis recomputed
    without a solve (every condition's verdict and numbers), and the family's ``determined`` (the
    matrices the FMU runs, the figures derived from the certified variables, the eigenvalues and zeros
    the card lists); then the certificate's checks. What no solver-free computation reproduces is the
    design's record, not a claim: ``search``, ``timing``, ``generator``, ``design_method``, the solver's
    word in ``certificate``, ltv-auid's least ``gamma``, and existence conditions that took a solve.

    Parameters
    ----------
    card : Card
        A card that passed the card schema.

    Returns
    -------
    list of Check
        Every check with its value and bound; the card is certified when all hold.
    """
    family = available_family(card.family, "design card family")
    try:
        problem = problem_from_data(card.data["problem"], default_name=card.name)
    except ProblemError as exc:
        raise CardError(f"design card problem: {exc}") from None
    consistency = consistency_checks(card.data, plant_record(problem))
    if all(c.holds for c in consistency):              # the family's record may assume the plant's sizes
        analysis = family.analyse(problem, solver=False)
        found = existence_checks(card.data.get("existence"), analysis.existence, problem.plant.n,
                                 plant_scale(problem.data.get("plant")))
        if analysis.existence.exists:                  # what a design of the problem determines
            consistency += consistency_checks(card.data, family.determined(problem, card.data, analysis))
        consistency += found
    if not all(c.holds for c in consistency):
        return consistency               # a certificate of another problem's matrices proves nothing here
    return consistency + family.verify(card) + _cap_checks(card.data, problem)


def recheck(card: Card) -> list:
    """Insist that every check of a card's certificate holds at its stored matrices.

    ``certificate.verified`` is only a claim of whoever wrote the card; ``build``, ``cosim`` and
    ``verify`` re-run the checks before they use a card.

    Parameters
    ----------
    card : Card
        A card that passed the card schema.

    Returns
    -------
    list of Check
        The checks (all of them hold).

    Raises
    ------
    CardError
        When a matrix the checks need is missing or misshapen, or a check fails (named, with
        its value and bound).
    """
    try:
        checks = verify(card)
        failed = [c for c in checks if not c.holds]
    except KeyError as exc:
        raise CardError(f"design card: its certificate cannot be re-checked: the key {str(exc.args[0])[:60]!r} is "
                        "missing (a matrix, or a figure of the card)") from None
    except (TypeError, ValueError, IndexError, AttributeError, ZeroDivisionError, OverflowError,
            np.linalg.LinAlgError) as exc:                 # a malformed card: its arrays do not fit together
        raise CardError(f"design card: its certificate cannot be re-checked ({type(exc).__name__}: "
                        f"{str(exc)[:200]})") from None
    if failed and failed[0].name.endswith(DETERMINED):
        c = failed[0]
        how = "" if not (c.bound and math.isfinite(c.value)) else \
            f" (relative difference {c.value:.3g}, allowed {c.bound:.1g})"
        raise CardError(f"design card: {c.name[:-len(DETERMINED)]} is not what the card's problem determines{how}: "
                        "the card was changed after its design, or designed for another problem")
    if failed:
        c = failed[0]
        raise CardError(f"design card: the certificate does not hold at the stored matrices: {c.name} = {c.value:.6g}, "
                        f"required {'<=' if c.at_most else '>='} {c.bound:.6g}" +
                        (f" (and {len(failed) - 1} more check(s))" if len(failed) > 1 else ""))
    return checks


def assemble_card(problem: Problem, result: DesignResult, existence: Existence, started: float) -> Card:
    """The design card of a finished design (shared by every family).

    Parameters
    ----------
    problem : Problem
    result : DesignResult
        The family's design.
    existence : Existence
        The existence analysis the design passed.
    started : float
        ``time.perf_counter()`` when the design started (``timing.total_s`` ends here).

    Returns
    -------
    Card
    """
    plant = problem.plant
    systems = () if result.lmi is None else result.lmi if isinstance(result.lmi, tuple) else (result.lmi,)
    data = {
        "format": FORMAT,
        "version": VERSION,
        "family": problem.family,
        "name": problem.name,
        "generator": f"uiofmu {__version__} (python {platform.python_version()})",
        "dims": {"n": plant.n, "m": plant.m, "p": plant.p, "q": plant.q, "nz": result.nz,
                 **({} if result.nf is None else {"nf": result.nf})},
        "time": plant.time,
        "dt": result.dt,
        "schedule": result.schedule,
        "initial": {"xhat0": to_lists(np.zeros(plant.n) if result.xhat0 is None else result.xhat0)},
        **to_lists(result.results),
        "existence": to_lists(existence.to_data()),
        "matrices": to_lists(result.matrices),
        "certificate": to_lists(result.certificate),
        "problem": problem.data,
        "kernel": FAMILIES[problem.family].kernel,
        "timing": {"total_s": time.perf_counter() - started,
                   "lmi_assembly_s": sum(s.assembly_time for s in systems),
                   "solver_s": sum(s.solver_time for s in systems), "solves": sum(s.solves for s in systems),
                   "backend": systems[0].backend if systems else "none"},
    }
    # The card checked as any reader checks it (check_card), and its ports declared from the matrices that check
    # returns: the check of the ports against the same matrices, which a card read later gets, holds by construction.
    matrices = check_card(data)
    data["ports"] = [port.to_data() for port in declared_ports(data, matrices)]
    return Card(data, matrices)
