"""The observer families uiofmu knows: the one place that names them.

Every other list of families is derived from :data:`FAMILIES`: the names a problem file or a
card may give (:data:`KNOWN`), the ones this version designs (:data:`AVAILABLE`, those with a
module in :mod:`uiofmu.families`), the command line's help. A new family adds one entry here
and its module (see the README, "How to add a family"). This module imports nothing, so the
runtime copy inside FMUs carries it along with the card schema.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Entry:
    """One family.

    Attributes
    ----------
    name : str
        The value of ``observer.family`` and of a card's ``family``.
    paper : str
        Where its design comes from (shown in help texts).
    module : str or None
        Its module in :mod:`uiofmu.families`; None while it is not available in this version.
    """

    name: str
    paper: str
    module: str | None


#: Every family, in the order help texts list them.
FAMILIES = {e.name: e for e in (
    Entry("lti-uio", "Darouach, Zasadzinski, Xu 1994 (seed 000)", "lti_uio"),
    Entry("ltv-auid", "Ichalal, Mammar, CDC 2019 (seed 000)", "ltv_auid"),
    Entry("switched", "Millerioux, Daafouz (seed 002)", "switched"),
    Entry("sampled-data", "Etienne, Langueh, Hetel, ECC 2023 (seed 004)", "sampled_data"),
    Entry("deadbeat-functional", "Fiacchini, Millerioux (seed 003)", "deadbeat_functional"),
    Entry("delayed-uio", "Fouka et al. (seed 001)", "delayed_uio"),
)}

#: Names a problem file or a card may give.
KNOWN = tuple(FAMILIES)

#: Names this version designs, builds and runs.
AVAILABLE = tuple(name for name, e in FAMILIES.items() if e.module)


def summary() -> str:
    """The available families as ``name: paper``, joined by semicolons, for help texts."""
    return "; ".join(f"{name}: {FAMILIES[name].paper}" for name in AVAILABLE)
