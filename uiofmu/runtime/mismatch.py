"""A plant other than the design model, on purpose: a seeded relative perturbation of its matrices (numpy only).

A plant FMU of matrices (linear or switched) takes the parameters ``mismatch`` (a relative standard deviation
``s >= 0``; 0: the design model exactly) and ``mismatch_seed``, and at the end of its initialisation replaces
every entry of ``A``, ``B`` and ``E`` by

    M_ij (1 + s g_ij),    g = sqrt(3) (2 U - 1),    U = (out >> 11) 2**-53,

``out`` the next 64-bit output of a SplitMix64 generator (:func:`uiofmu.runtime.switching.splitmix64`) started
at the seed's 64 bits (two's complement). ``g`` is uniform on [-sqrt(3), sqrt(3)): mean 0, variance 1. The
entries are drawn block by block (a switched plant's modes 1..N in order; a linear plant is one block), in
each block ``A`` then ``B`` then ``E``, each row by row; a zero entry takes its draw and stays zero. Every
operation is one IEEE rounding in a fixed order, so the C plant kernel (``uiofmu/fmu/c/kernel_plant.c``)
perturbs to the same bits. The term ``w`` and ``C`` stay the design's.
"""

from __future__ import annotations

import math

import numpy as np

from .splitmix import MASK, splitmix64

#: sqrt(3), correctly rounded (as C's sqrt(3.0)).
SQRT3 = math.sqrt(3.0)
#: 2**-53: ``(out >> 11) * UNIT`` is uniform on [0, 1), exact.
UNIT = 1.0 / 9007199254740992.0


def mismatch_problem(mismatch) -> str | None:
    """Why ``mismatch`` is not a relative standard deviation (a finite number >= 0), or None."""
    if not (math.isfinite(mismatch) and mismatch >= 0):
        return f"parameter mismatch = {mismatch!r} is not a finite number >= 0"
    return None


def perturb(blocks: list, mismatch: float, seed: int) -> list:
    """The blocks ``[(A, B, E), ...]`` with every entry of ``A``, ``B``, ``E`` perturbed (module docstring).

    Parameters
    ----------
    blocks : list of tuple of numpy.ndarray
        One ``(A, B, E)`` per mode (one for a linear plant): ``n x n``, ``n x m``, ``n x q``.
    mismatch : float
        The relative standard deviation ``s``, finite and >= 0; 0 returns copies of the blocks.
    seed : int
        The generator's seed (an fmi2Integer; its 64 bits in two's complement).

    Returns
    -------
    list of tuple of numpy.ndarray
        New arrays; entries that overflow are ``inf`` (the caller refuses them).
    """
    if mismatch == 0:
        return [tuple(np.array(M, dtype=float) for M in block) for block in blocks]
    state = int(seed) & MASK
    out = []
    for block in blocks:
        new = []
        for M in block:
            M = np.array(M, dtype=float)
            flat = M.reshape(-1)
            for e in range(flat.size):
                state, word = splitmix64(state)
                g = SQRT3 * (2.0 * ((word >> 11) * UNIT) - 1.0)
                flat[e] = float(flat[e]) * (1.0 + mismatch * g)
            new.append(M)
        out.append(tuple(new))
    return out


__all__ = ["SQRT3", "mismatch_problem", "perturb"]
