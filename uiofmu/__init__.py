"""uiofmu: unknown-input observers designed with LMIs, certified, and shipped as FMUs.

The Python API follows the data flow of the command line::

    problem = uiofmu.load_problem("examples/seed000_example1.toml")
    report  = uiofmu.check(problem)            # existence conditions
    card    = uiofmu.design(problem)           # LMI design + independent re-check
    card.write("design.json")
    rt      = uiofmu.Runtime(card)             # the reference runtime (numpy only)
"""

__version__ = "0.1.0"

from .card import Card, read_card  # noqa: E402
from .errors import CardError, InfeasibleError, NoObserverError, ProblemError, UserError  # noqa: E402
from .plant import Plant, plant_from_statespace  # noqa: E402
from .problem import Problem, load_problem, make_problem  # noqa: E402
from .runtime import Runtime  # noqa: E402


def check(problem):
    """Existence analysis (see :func:`uiofmu.synthesis.check`)."""
    from .synthesis import check as _check
    return _check(problem)


def design(problem):
    """LMI design with a verified certificate (see :func:`uiofmu.synthesis.design`)."""
    from .synthesis import design as _design
    return _design(problem)


__all__ = ["Card", "CardError", "InfeasibleError", "NoObserverError", "Plant", "Problem", "ProblemError",
           "Runtime", "UserError", "check", "design", "load_problem", "make_problem", "plant_from_statespace",
           "read_card"]
