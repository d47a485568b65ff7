"""The observer's gains: their size, their size against the plant's, and a cap on them.

An observer multiplies what it measures by its gains, sensor noise included: a gain of 1e7
turns a noise of 1e-6 on an output into an error of about 10 on the estimate. Each family says
which of its card's matrices are its gains (its ``gain_figures(card_data)``: the gains the
design chooses, ``||C||`` and the size of the plant's matrix that the gains correct, in the
observer's time base). From them:

* the largest gain ``g = max ||K||_2`` over the gains (every mode, interval or vertex);
* its size against the plant's, ``ratio = g ||C||_2 / ||A||_2``: the same in any unit of the state
  and any unit of the output (not of their relative scales), 1 when the correction ``K C`` is as large
  as the plant's own map. An
  output noise of a fraction ``eps`` of the output's size moves the estimate by up to about
  ``ratio * eps`` of the state's size (per step of a discrete observer, per unit of ``1/||A||``
  of a continuous one). Above :data:`LARGE_GAIN_RATIO` ``uiofmu design`` warns;
* ``observer.gain_cap``: a bound on ``g`` that every LMI design takes as an LMI of its system
  (:func:`cap_lmis`), so that a ``"max"`` search finds the fastest decay compatible with it,
  and that :func:`cap_check` re-checks at a card's stored gains.
"""

from __future__ import annotations

import numpy as np

from .certificate import Check, figure_text
from .lmi import Lmi
from .runtime.tolerances import POINT_RTOL

#: ``uiofmu design`` warns above this ratio ``||K|| ||C|| / ||A||``: an output noise of 0.1 % of the
#: output's size then moves the estimate by the state's own size.
LARGE_GAIN_RATIO = 1e3

#: Significant digits of the printed gain: it is read off the design's point, which the solver's tolerance
#: determines less finely than an optimal value (see :func:`uiofmu.certificate.figure_digits`).
GAIN_DIGITS = 2

#: A stored gain passes its cap up to this relative rounding: the cap is a non-strict LMI, which the
#: re-check of the solver's point accepts to :data:`~uiofmu.runtime.tolerances.POINT_RTOL` of its size.
CAP_RTOL = 1e3 * POINT_RTOL


def two_norms(matrices) -> np.ndarray:
    """The 2-norms of a list of matrices or stacks of matrices (empty ones count 0)."""
    out = [np.linalg.norm(np.asarray(m, dtype=float).reshape(-1, *np.shape(m)[-2:]), 2, axis=(-2, -1))
           for m in matrices if np.size(m)]
    return np.concatenate(out) if out else np.zeros(1)


def gain_figures(card_data: dict) -> tuple[float, float]:
    """The largest gain ``max ||K||_2`` of a card and its ratio ``g ||C|| / ||A||`` (see the module).

    Parameters
    ----------
    card_data : dict
        A design card's data (its family gives ``gain_figures``).

    Returns
    -------
    (float, float)
        The largest gain and its ratio to the plant's scale.
    """
    from .families import available_family

    gains, c_norm, a_norm = available_family(card_data["family"], "design card family").gain_figures(card_data)
    largest = float(two_norms(gains).max())
    return largest, largest * c_norm / max(a_norm, 1e-300)


def gain_lines(card_data: dict, figures: bool = True) -> list[str]:
    """The lines ``uiofmu design`` prints of the gains: the largest and its ratio (with ``figures``), and a
    warning when the ratio is above :data:`LARGE_GAIN_RATIO`.

    The gain of an LMI design is read off the solver's point, not an optimal value: another BLAS kernel's
    point can have another gain (the badly scaled DC motor of ``tests/same_answers.py``: 200 or 160), so the
    text every machine prints alike leaves the figures out (``figures=False``); the warning is a verdict
    with no figure in it.
    """
    largest, ratio = gain_figures(card_data)
    gain, scaled = figure_text(largest, GAIN_DIGITS), figure_text(ratio, GAIN_DIGITS)
    cap = (card_data.get("problem", {}).get("observer") or {}).get("gain_cap")
    lines = [f"  largest gain     {gain} (2-norm; {scaled} x the plant's scale ||A|| / ||C||"
             + (f"; gain_cap {cap:g})" if isinstance(cap, (int, float)) else ")")] if figures else []
    if ratio > LARGE_GAIN_RATIO:
        lines.append(f"  [warning] the gain is large against the plant's scale (above {LARGE_GAIN_RATIO:g} x "
                     "||A|| / ||C||): sensor noise reaches the estimate multiplied by it; set observer.gain_cap "
                     "(it costs decay), or rescale the units")
    return lines


def cap_check(card_data: dict, cap: float) -> Check:
    """``max ||K||_2 <= gain_cap`` at a card's stored gains, up to :data:`CAP_RTOL` of rounding."""
    largest, _ = gain_figures(card_data)
    return Check(f"largest gain (2-norm) <= observer.gain_cap = {cap:g}", largest, cap * (1.0 + CAP_RTOL))


def cap_lmis(cap: float, groups, s, ops) -> list:
    """The LMIs that bound every gain ``H^-1 Y`` (or ``Y' H^-T``) by ``cap``, homogeneous in the variables.

    With a scalar variable ``s``: ``H + H' >= 2 s I`` gives ``sigma_min(H) >= s`` (``x'Hx >= s |x|^2``), and
    ``[[cap s I, Y], [Y', cap s I]] >= 0`` gives ``||Y|| <= cap s``, so ``||H^-1 Y|| <= cap``; ``s >= 1``
    normalises them (the largest-margin problem turns it into ``s >= t`` as it does ``X >= I``).

    Parameters
    ----------
    cap : float
        ``observer.gain_cap``.
    groups : list of (str, H, list of (str, Y))
        The square matrix variable the gains are divided by (a Lyapunov matrix or a slack), with its
        name, and the product variables of its gains, with theirs.
    s : variable
        The scalar variable ``s``.
    ops : namespace
        The LMI builder's ``ops``.

    Returns
    -------
    list of Lmi
    """
    out = [Lmi("gain_cap: s >= 1", s * ops.eye(1) - ops.eye(1), strict=False)]
    for h_name, H, products in groups:
        n = H.shape[0]
        out.append(Lmi(f"gain_cap: {h_name} + {h_name}' >= 2 s I", H + H.T - (2.0 * s) * ops.eye(n), strict=False))
        for name, Y in products:
            p = Y.shape[1]
            out.append(Lmi(f"gain_cap: ||{name}|| <= cap s", ops.bmat([[(cap * s) * ops.eye(n), Y],
                                                                       [Y.T, (cap * s) * ops.eye(p)]]),
                           strict=False))
    return out


__all__ = ["CAP_RTOL", "GAIN_DIGITS", "LARGE_GAIN_RATIO", "cap_check", "cap_lmis", "gain_figures", "gain_lines",
           "two_norms"]
