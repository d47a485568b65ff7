"""Observer families: one module each, all with the same contract.

A family module (named in :data:`uiofmu.runtime.registry.FAMILIES`) provides:

``NAME``
    Its name (the registry's key).
``parse_options(table, plant)``
    Read the family's keys of ``[observer]`` into a frozen options object, whose ``step`` is the
    communication step a co-simulation of the observer takes by default (the plant FMU's
    default experiment uses it).
``analyse(problem, solver=True) -> Analysis``
    The existence analysis, and whatever of it the design reuses. With ``solver=False`` it leaves
    out the conditions that take a solve (:attr:`uiofmu.existence.Condition.solver`): what
    :func:`uiofmu.verify` recomputes.
``design(problem, analysis) -> DesignResult``
    Solve and certify (``analysis.existence`` holds); :func:`uiofmu.synthesis.design` times
    it, fills in the defaults and assembles the card. Its ``results`` hold the card's ``noise`` section
    (:mod:`uiofmu.noise`: the certified noise gains, or the reason there are none), which ``determined``
    and ``verify`` account for (what the problem determines of it, the re-check of each gain it states).
``determined(problem, card_data, analysis) -> dict``
    What the card's problem, its analysis (``analyse(problem, solver=False)``) and its certified
    variables (e.g. a gain) determine of the card: dotted card paths to values (the plant's
    matrices the FMU runs, the schedule, the figures derived from the certificate, the zeros and
    eigenvalues the card lists: :class:`uiofmu.consistency.Spectrum`), compared with the card by
    :func:`uiofmu.consistency.consistency_checks` before :func:`verify` runs. A figure no
    solver-free computation reproduces (the search, the solver's status) is the design's record.
``verify(card) -> list of Check``
    The certificate's checks at a card's stored matrices, without any solver.
``gain_figures(card_data) -> (gains, ||C||, ||A||)``
    The gains its design chooses (matrices or stacks), ``||C||`` and the size of the plant's matrix they
    correct (:mod:`uiofmu.gains`: the largest gain ``design`` prints and ``observer.gain_cap`` bounds; an
    LMI family takes the cap into its LMIs with :func:`uiofmu.gains.cap_lmis`).
``certified_bound(card, e0, d)`` (where its registry entry says ``own_bound``)
    The bound on ``||e_k||`` of a run, when it is not ``overshoot * decay**k * ||e_0||``.

What the registry entry (:class:`uiofmu.runtime.registry.Entry`) says of the family is not repeated in
its module: the kernel of its cards, the plant kinds it designs for, whether its design is a closed
form (``observer.gain_cap`` then only checks its gains) and whether it has its own bound.

Families differ in how they design matrices and how the schedule picks them, never in how
the runtime steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import import_module

from ..runtime.errors import CardError, ProblemError
from ..existence import Existence
from ..runtime.registry import AVAILABLE, FAMILIES, KNOWN


@dataclass(frozen=True)
class Analysis:
    """What :func:`analyse` found: the existence report and the family's own findings.

    Attributes
    ----------
    existence : Existence
    data : dict
        Whatever of the analysis the design reuses (sampled plants, fixed modes, limits).
    """

    existence: Existence
    data: dict = field(default_factory=dict)


@dataclass
class DesignResult:
    """A family's finished design, before it becomes a card.

    Attributes
    ----------
    nz : int
        Dimension of the observer's internal state ``z``.
    dt : float or None
        Design period (None for interval schedules).
    schedule : dict
        The runtime schedule entry (``kind`` and its data).
    matrices : dict
        Runtime matrices (see :data:`uiofmu.runtime.card.RUNTIME_SHAPES`) plus the family matrices
        users look at and its checks use.
    certificate : dict
        From :func:`uiofmu.certificate.certificate`.
    results : dict
        Family results at the card's top level (``decay_bound``, ``overshoot_bound``, ...).
    lmi : LmiSystem, tuple of LmiSystem, or None
        The design's LMI system(s) (their assembly time, solves and solver time add up in ``timing``);
        None for a design without one.
    xhat0 : array_like or None
        Initial estimate (None: zeros).
    nf : int or None
        A functional observer's number of functionals (the card's ``dims.nf``: it outputs ``zhat``, not
        ``xhat``); None for an observer of the state.

    The runtime kernel of the card is the family's (:attr:`uiofmu.runtime.registry.Entry.kernel`).
    """

    nz: int
    dt: float | None
    schedule: dict
    matrices: dict
    certificate: dict
    results: dict
    lmi: object
    xhat0: object = None
    nf: int | None = None


def available_family(name: str, key: str = "observer.family"):
    """The module implementing family ``name``.

    Parameters
    ----------
    name : str
        A family name.
    key : str
        Where the name came from, for the message (``"design card family"``).

    Returns
    -------
    module

    Raises
    ------
    ProblemError
        For a family that is unknown or not available in this version (a card's family:
        CardError).
    """
    error = CardError if key.startswith("design card") else ProblemError
    if name not in KNOWN:
        raise error(f"{key}: unknown family {name!r} (families: {', '.join(KNOWN)})")
    if name not in AVAILABLE:
        raise error(f"{key}: {name!r} is not available in this version of uiofmu "
                    f"(available: {', '.join(sorted(AVAILABLE))})")
    return import_module(f"{__name__}.{FAMILIES[name].module}")


def certified_bound(card, e0, d):
    """The certified bound on ``||e_k||`` of a run, k = 0..len(d)-1.

    Parameters
    ----------
    card : Card
    e0 : (n,) array
        The initial error ``x_0 - xhat_0``.
    d : (K+1, q) array
        The unknown input held over each step (the bound of a family whose decoupling is
        only asymptotic depends on it).

    Returns
    -------
    numpy.ndarray or None
        None when the design certifies no bound.
    """
    from ..certificate import geometric_bound

    module = available_family(card.family, "design card family")
    if FAMILIES[card.family].own_bound:
        return module.certified_bound(card, e0, d)
    if card.data.get("decay_bound") is None:
        return None
    return geometric_bound(card, e0, d)
