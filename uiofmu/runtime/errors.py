"""Exceptions of uiofmu.

Every error a user can fix (a bad problem file, a value out of range, an observer that does
not exist, an infeasible LMI, a corrupt design card) is a :class:`UserError`: the command
line prints its message on one line and exits with code 2. Anything else is a bug (exit 1).
"""


class UserError(Exception):
    """Base of all errors a user can fix; the message names the key or the violated condition.

    ``user_error`` marks the class for the command line also in the copies of this module that
    travel inside FMUs (the copy's classes are other classes with the same marker).
    """

    exit_code = 2
    user_error = True


class ProblemError(UserError, ValueError):
    """A problem file (or a plant given from Python) is malformed or inconsistent."""


class CardError(UserError, ValueError):
    """A design card is malformed, of an unknown format, or fails its own certificate."""


class NoObserverError(UserError):
    """The existence conditions of the chosen observer family do not hold."""


class InfeasibleError(UserError):
    """An LMI problem is infeasible, or the solver's answer does not survive the re-check."""


class FmuError(UserError):
    """An FMU could not be built, loaded or driven (the message says which and why)."""


class NumericalError(UserError):
    """Linear algebra failed on the numbers of a problem (badly scaled or overflowing data)."""
