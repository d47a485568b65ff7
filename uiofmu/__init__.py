"""uiofmu: unknown-input observers designed with LMIs, certified, and shipped as FMUs.

The Python API follows the data flow of the command line::

    import uiofmu
    problem = uiofmu.load_problem("examples/seed000_example1.toml")
    report  = uiofmu.check(problem)            # existence conditions
    card    = uiofmu.design(problem)           # LMI design + independent re-check
    card.write("design.json")
    rt      = uiofmu.Runtime(card)             # the reference runtime (numpy only)

Names are imported on first use, so ``import uiofmu.runtime.observer`` stays numpy-only.
"""

from importlib import import_module

__version__ = "0.1.0"

_EXPORTS = {
    "Card": "runtime.card", "read_card": "runtime.card",
    "CardError": "runtime.errors", "InfeasibleError": "runtime.errors", "NoObserverError": "runtime.errors",
    "ProblemError": "runtime.errors", "UserError": "runtime.errors", "FmuError": "runtime.errors",
    "Plant": "plant", "plant_from_statespace": "plant",
    "Problem": "problem", "load_problem": "problem", "make_problem": "problem",
    "Runtime": "runtime.observer",
    "check": "synthesis", "design": "synthesis", "verify": "synthesis",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'uiofmu' has no attribute {name!r}")
