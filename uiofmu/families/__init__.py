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

from ..errors import ProblemError

#: Families available in this version, and their modules.
FAMILIES = {"lti-uio": "lti_uio", "sampled-data": "sampled_data", "ltv-auid": "ltv_auid"}


def family_module(name: str):
    """The module implementing family ``name``."""
    if name not in FAMILIES:
        raise ProblemError(f"observer.family: {name!r} is not available in this version of uiofmu "
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

    module = family_module(card.family)
    if hasattr(module, "certified_bound"):
        return module.certified_bound(card, e0, d)
    if card.data.get("decay_bound") is None:
        return None
    return geometric_bound(card, e0, d)
