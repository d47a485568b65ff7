"""SplitMix64 (Steele, Lea, Flood 2014), the generator the plant FMUs draw from in Python and C alike.

A switched plant under rule ``random`` draws its modes from it (:mod:`uiofmu.runtime.switching`), a plant
with a ``mismatch`` its perturbation (:mod:`uiofmu.runtime.mismatch`); the C plant kernel runs the same
arithmetic on ``uint64_t``, so both backends draw the same numbers.
"""

from __future__ import annotations

#: The 64-bit mask: a Python integer taken modulo 2**64.
MASK = (1 << 64) - 1


def splitmix64(state: int) -> tuple[int, int]:
    """One step of SplitMix64: ``(new state, 64-bit output)``."""
    state = (state + 0x9E3779B97F4A7C15) & MASK
    z = state
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return state, z ^ (z >> 31)


__all__ = ["MASK", "splitmix64"]
