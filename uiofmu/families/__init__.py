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
FAMILIES = {"lti-uio": "lti_uio", "sampled-data": "sampled_data"}


def family_module(name: str):
    """The module implementing family ``name``."""
    if name not in FAMILIES:
        raise ProblemError(f"observer.family: {name!r} is not available in this version of uiofmu "
                           f"(available: {', '.join(sorted(FAMILIES))})")
    return import_module(f"{__name__}.{FAMILIES[name]}")
