"""The observer families uiofmu knows: the one place that names them.

Every other list of families is derived from :data:`FAMILIES`: the names a problem file or a
card may give (:data:`KNOWN`), the ones this version designs (:data:`AVAILABLE`, those with a
module in :mod:`uiofmu.families`), the command line's help, the FMU catalogue's sections
(:data:`uiofmu.catalogue.FAMILIES`) and the random campaign's families
(:data:`uiofmu.families.random_plants.FAMILY_CODES`). An entry names the runtime kernel of its cards
(:mod:`uiofmu.runtime.kernels`) and the plant kinds its designs accept (:mod:`uiofmu.plant_kinds`). A new
family adds one entry here and its module (the checklist "A family" of ``docs/contributing.md``). This module
imports nothing, so the runtime copy inside FMUs carries it along with the card schema.
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
    kernel : str
        The runtime kernel that steps its observers (a key of :data:`uiofmu.runtime.kernels.KERNELS`).
    plants : tuple of str
        The plant kinds it designs for (keys of :data:`uiofmu.plant_kinds.PLANT_KINDS`); a problem with a plant
        of another kind is refused (a linear plant by the family's options, which say what it needs).
    certifies : str
        What its designs certify, one line (the FMU catalogue's section text).
    section : int
        The place of its section in the FMU catalogue (``fmus/README.md``).
    random_code : int or None
        The code that decorrelates its stream in random campaigns; None when random plants do not cover it.
    closed_form : bool
        Whether its design is a closed form (no LMIs, so no gain cap shapes their feasibility).
    own_bound : bool
        Whether its module computes its certified error bound (``certified_bound``); else the geometric bound
        of the card's ``decay_bound`` and ``overshoot_bound``.
    feedthrough : bool
        Whether it designs for a linear plant measured with direct feedthrough (``y = C x + D u + F d``);
        a plant with ``[plant] D`` or ``F`` is refused to the others.
    """

    name: str
    paper: str
    module: str | None
    kernel: str = "affine"
    plants: tuple = ("linear",)
    certifies: str = ""
    section: int = 0
    random_code: int | None = None
    closed_form: bool = False
    own_bound: bool = False
    feedthrough: bool = False


#: Every family, in the order help texts list them.
FAMILIES = {e.name: e for e in (
    Entry("lti-uio", "Darouach, Zasadzinski, Xu 1994 (seed 000)", "lti_uio", section=1, random_code=1,
          feedthrough=True,
          certifies="classical unknown-input observer (constant step): a certified geometric decay of the error"),
    Entry("ltv-auid", "Ichalal, Mammar, CDC 2019 (seed 000)", "ltv_auid", section=2, random_code=2, own_bound=True,
          certifies="asymptotic unknown-input decoupling, time-varying gains (constant step): a certified bound "
                    "through the recursion b_k"),
    Entry("switched", "Millerioux, Daafouz (seed 002)", "switched", plants=("linear", "switched"), section=4,
          certifies="switched linear plant, the mode known at every step: a certified decay under arbitrary "
                    "switching"),
    Entry("sampled-data", "Etienne, Langueh, Hetel, ECC 2023 (seed 004)", "sampled_data", section=3, random_code=3,
          certifies="sampled-data observer: a certified decay for every sequence of the design intervals"),
    Entry("deadbeat-functional", "Fiacchini, Millerioux (seed 003)", "deadbeat_functional", kernel="window",
          plants=("lpv",), section=5, closed_form=True,
          certifies="dead-beat functional observer of an LPV plant: the functional G x exactly, from the first "
                    "full output window (no decay: exactness)"),
    Entry("delayed-uio", "Fouka et al. (seed 001)", "delayed_uio", kernel="delayed", plants=("parametric",),
          section=6,
          certifies="delayed UIO with parameter identification (continuous time, integrated in the FMU): a decay "
                    "bound on the design's premise set only, and a validity flag"),
)}

#: Names a problem file or a card may give.
KNOWN = tuple(FAMILIES)

#: Names this version designs, builds and runs.
AVAILABLE = tuple(name for name, e in FAMILIES.items() if e.module)


def summary() -> str:
    """The available families as ``name: paper``, joined by semicolons, for help texts."""
    return "; ".join(f"{name}: {FAMILIES[name].paper}" for name in AVAILABLE)
