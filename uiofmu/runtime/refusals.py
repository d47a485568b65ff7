"""The refusals the Python runtime and the C kernels both say, written once (standard library only).

Each message is a template whose fields name their kind after a colon: ``{h:num}`` a number as
Python's ``repr`` writes it (the C kernels' ``uiofmu_num`` writes the same text), ``{i:int}`` an
integer, ``{name:text}`` text, ``{rtol:g}`` a number in ``%g`` form, ``{policy:quoted}`` a word in
single quotes. :func:`refusal` fills a template in Python; the C backend writes each one as a printf
format into the sources of every C FMU (``uiofmu_refusals.h``, ``UIOFMU_REFUSAL_<KEY>``), whose
arguments the C code passes in the order of the fields (:func:`fields`).
"""

from __future__ import annotations

from string import Formatter

#: How a field of each kind is written in Python.
KINDS = {"num": repr, "int": str, "text": str, "g": lambda v: format(v, "g"), "quoted": repr}

#: The shared refusals, by key.
REFUSALS = {
    # a discrete plant (linear, switched, LPV) given another step than its period: fmi2Discard
    "plant_off_period": "this discrete plant steps at dt = {dt:num} s and received h = {h:num} s",
    # an observer with a constant schedule given another step than its period: fmi2Discard
    "observer_off_period": "this observer was designed for steps of dt = {dt:num} s and received h = {h:num} s "
                           "(step_policy = {policy:quoted})",
    # an interval schedule given a step that is none of its intervals (step_policy 'error'): fmi2Discard
    "not_a_design_interval": "step h = {h:num} s is not one of the design intervals {{{listed:text}}} s "
                             "(tolerance {rtol:g} relative; step_policy = 'error')",
    # an input that is not finite at a step (``at``: " at step k = 3", or empty): fmi2Error
    "input_not_finite": "input {name:text}[{index:int}] = {value:text}{at:text} is not finite",
}


def fields(key: str) -> list:
    """The ``(name, kind)`` of each field of the refusal ``key``, in the order of its text."""
    return [(name, kind) for _, name, kind, _ in Formatter().parse(REFUSALS[key]) if name is not None]


def refusal(key: str, **values) -> str:
    """The refusal ``key`` with its fields filled from ``values`` (each written as its kind says).

    Examples
    --------
    >>> refusal("plant_off_period", dt=0.1, h=0.2)
    'this discrete plant steps at dt = 0.1 s and received h = 0.2 s'
    """
    return "".join(text + (KINDS[kind](values[name]) if name is not None else "")
                   for text, name, kind, _ in Formatter().parse(REFUSALS[key]))


__all__ = ["KINDS", "REFUSALS", "fields", "refusal"]
