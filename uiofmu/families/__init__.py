"""Observer families. Each module provides the same three functions:

``parse_options(table, plant)``
    Read the family's keys of ``[observer]`` into a frozen options object.
``check(problem)``
    The existence analysis, an :class:`~uiofmu.existence.Existence`.
``design(problem)``
    Solve, verify and return a :class:`~uiofmu.card.Card`.

Families differ in how they design matrices and how the schedule picks them, never in
how the runtime steps.
"""

from __future__ import annotations

from importlib import import_module

from ..errors import CardError, ProblemError

#: Families available in this version, and their modules.
FAMILIES = {"lti-uio": "lti_uio", "sampled-data": "sampled_data", "ltv-auid": "ltv_auid"}


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
        For a family that is not available in this version (a card's family: CardError).
    """
    if name not in FAMILIES:
        error = CardError if key.startswith("design card") else ProblemError
        raise error(f"{key}: {name!r} is not available in this version of uiofmu "
                    f"(available: {', '.join(sorted(FAMILIES))})")
    return import_module(f"{__name__}.{FAMILIES[name]}")



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
    if hasattr(module, "certified_bound"):
        return module.certified_bound(card, e0, d)
    if card.data.get("decay_bound") is None:
        return None
    return geometric_bound(card, e0, d)
