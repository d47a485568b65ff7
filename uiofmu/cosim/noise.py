"""Measurement noise in a co-simulation: its text (``--noise y=STD[,SEED]``), its samples and what it does to
the estimate.

The master adds the noise ``v_k`` to the plant's ``y`` on its way to the observer (the plant's state stays the
truth) and runs a noise-free twin of the observer, a second instance of the same FMU fed the plant's own ``y``,
in the same loop. The two estimates differ by the noise's part of the error alone, so

    noise_gain_measured = ||e - e_twin||_2 / ||v||_2 = sqrt(sum_k ||xhat_k - xhat_twin_k||^2) / sqrt(sum_k ||v_k||^2)

is compared with the card's certified l2 gain ``noise.gain_y`` (from ``v`` to the error, with the initial
condition's term apart: the twin carries it). A measured gain above the certified one is a false certificate.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..runtime.errors import ProblemError

#: Longest ``--noise`` text read (a longer one is refused before it is parsed).
MAX_NOISE_TEXT = 2000
#: Most outputs a list of standard deviations may name.
MAX_CHANNELS = 10_000
#: Relative slack of the gain comparison (round-off of the two observers' sums).
GAIN_RTOL = 1e-9

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_TEXT = re.compile(r"^(?P<what>[a-z]+)=(?P<std>\[[^\[\]]*\]|[^,\[\]]+)(?:,(?P<seed>[^,]*))?$")


@dataclass(frozen=True)
class Noise:
    """White Gaussian noise added to one signal of a run.

    Attributes
    ----------
    signal : str
        ``y`` (measurement noise, added between the plant and the observer) or ``w`` (process noise).
    std : tuple of float
        The standard deviation: one for every element, or one per element.
    seed : int
        The seed of its generator (``numpy.random.default_rng``).
    """

    signal: str
    std: tuple
    seed: int = 0

    def text(self) -> str:
        """The ``--noise`` text of this noise."""
        std = repr(self.std[0]) if len(self.std) == 1 else "[" + ",".join(repr(s) for s in self.std) + "]"
        return f"{self.signal}={std},{self.seed}"

    def stds(self, size: int) -> np.ndarray:
        """The standard deviation of each of ``size`` elements (refuses a list of another length)."""
        if len(self.std) == 1:
            return np.full(size, self.std[0])
        if len(self.std) != size:
            raise ProblemError(f"--noise {self.signal}=...: {len(self.std)} standard deviations for {size} "
                               f"element(s) of {self.signal}; give one number or {size}")
        return np.asarray(self.std, dtype=float)

    def samples(self, points: int, size: int) -> np.ndarray:
        """``(points, size)`` samples: row k is the noise at communication point t_k, the same for a seed."""
        stds = self.stds(size)
        return np.random.default_rng(self.seed).standard_normal((points, size)) * stds


def _std(text: str, what: str) -> float:
    if not re.fullmatch(_NUMBER, text.strip()):
        raise ProblemError(f"--noise {what}: the standard deviation {text.strip()[:40]!r} is not a number")
    value = float(text)
    if not math.isfinite(value) or value < 0:
        raise ProblemError(f"--noise {what}: the standard deviation {text.strip()[:40]} must be a finite number >= 0")
    return value


def parse_noise(text: str) -> Noise:
    """A :class:`Noise` from its text ``SIGNAL=STD[,SEED]``, as untrusted input.

    ``SIGNAL`` is ``y`` or ``w``; ``STD`` a number >= 0, or a list ``[S1,S2,...]`` with one per element;
    ``SEED`` an integer from 0 to 2**63 - 1 (default 0). At least one standard deviation is above 0.

    Raises
    ------
    ProblemError
        One line naming what is wrong.
    """
    if not isinstance(text, str):
        raise ProblemError(f"--noise: expected a text SIGNAL=STD[,SEED], found a {type(text).__name__}")
    if len(text) > MAX_NOISE_TEXT:
        raise ProblemError(f"--noise: {len(text)} characters, more than {MAX_NOISE_TEXT}")
    match = _TEXT.match(text.strip())
    if match is None:
        raise ProblemError(f"--noise {text[:60]!r}: expected y=STD[,SEED] or w=STD[,SEED], STD a number or a list "
                           "[S1,S2,...] (e.g. y=0.01,7 or y=[0.01,0.002],7)")
    what = match["what"]
    if what not in ("y", "w"):
        raise ProblemError(f"--noise {what}=...: the noise is added to y (measurement) or w (process), not {what}")
    std = match["std"]
    parts = std[1:-1].split(",") if std.startswith("[") else [std]
    if len(parts) > MAX_CHANNELS:
        raise ProblemError(f"--noise {what}=...: {len(parts)} standard deviations, more than {MAX_CHANNELS}")
    stds = tuple(_std(p, f"{what}=...") for p in parts)
    if not any(s > 0 for s in stds):
        raise ProblemError(f"--noise {what}=...: every standard deviation is 0 (no noise to measure a gain "
                           "with): leave --noise out")
    seed = match["seed"]
    if seed is None:
        return Noise(what, stds)
    if not re.fullmatch(r"\d{1,19}", seed.strip()) or int(seed) > 2 ** 63 - 1:
        raise ProblemError(f"--noise {what}=...: the seed {seed.strip()[:40]!r} is not an integer from 0 to 2**63 - 1")
    return Noise(what, stds, int(seed))


def noises(spec) -> dict:
    """``{signal: Noise}`` of a run's noise: None, a text, a :class:`Noise` or a list of them (one per
    signal; a signal named twice is refused)."""
    if spec is None:
        return {}
    items = [spec] if isinstance(spec, (str, Noise)) else list(spec)
    out: dict = {}
    for item in items:
        noise = item if isinstance(item, Noise) else parse_noise(item)
        if noise.signal in out:
            raise ProblemError(f"--noise {noise.signal}=... given twice: one noise per signal")
        out[noise.signal] = noise
    return out


def certified_noise_gain(card, key: str = "gain_y") -> float | None:
    """The card's certified l2 gain from measurement noise to the estimation error (``noise.gain_y``; with
    ``key = "gain_w"`` from process noise), or None where the card has none (an older card, or a family
    that certifies none)."""
    section = card.data.get("noise")
    if not isinstance(section, dict) or section.get("norm", "l2") != "l2":
        return None
    gain = section.get(key)
    return float(gain) if isinstance(gain, (int, float)) and not isinstance(gain, bool) else None


def gain_covers(card) -> str | None:
    """What the card's ``noise.gain_y`` bounds where its family states it (``noise.covers``: the delayed UIO's holds
    with its premises at their noise-free values, which its FMU does not keep), else None: a gain of the whole loop,
    which a measurement can refute."""
    section = card.data.get("noise")
    covers = section.get("covers") if isinstance(section, dict) else None
    return covers if isinstance(covers, str) and covers else None


def _second_half_rms(err: np.ndarray) -> list:
    half = err[len(err) // 2:]
    return np.sqrt(np.mean(half * half, axis=0)).tolist() if len(half) else []


def noise_metrics(card, v: np.ndarray, estimate: np.ndarray, twin: np.ndarray, true: np.ndarray, dhat=None,
                  d=None, *, noise: Noise | None = None, quantum: float | None = None) -> dict:
    """The metrics of a run with measurement noise (or an output quantum).

    Parameters
    ----------
    card : Card
    v : (K+1, p) array
        What the observer received beyond the plant's ``y`` at every point (the noise, and the
        quantisation's error).
    estimate, twin : (K+1, .) arrays
        The estimate of the observer fed the noisy ``y`` and of its noise-free twin.
    true : (K+1, .) array
        What they estimate (``x``; NaN rows, as a functional observer's first ones, are left out).
    dhat, d : arrays, optional
        The noisy observer's unknown-input estimate and the input held over each step.
    noise : Noise, optional
        The white noise added to ``y``.
    quantum : float, optional
        The output quantum Q (``y`` rounded to multiples of it after the noise).

    Returns
    -------
    dict
        ``noise_gain_certified`` (the card's ``noise.gain_y`` or None), ``noise_gain_measured``
        (``||e - e_twin||_2 / ||v||_2``, sums over the points), ``noise_gain_respected`` (measured <=
        certified (1 + :data:`GAIN_RTOL`); None without a certified gain, and None where the gain holds on
        premises the run does not keep: ``noise_gain_covers``, :func:`gain_covers`), ``noise_gain_ratio``,
        ``noise_std_norm`` (``||sigma||`` of the effective std per output, ``sqrt(std^2 + Q^2 / 12)``: a
        quantum's rounding error as uniform noise), ``noise_rms_error`` and
        ``noise_dhat_rms_error`` (of the observer fed the noisy ``y``, over the second
        half of the run, per element), and ``noise``: the std per output, the seed and its text (with noise),
        the quantum (or None), the effective std, the norm of ``v``, ``rms_error_noise_free`` (the twin's,
        the same half) and what the bound check is made on.
    """
    std = noise.stds(v.shape[1]) if noise is not None else np.zeros(v.shape[1])
    effective = np.sqrt(std ** 2 + (quantum or 0.0) ** 2 / 12)
    diff = np.asarray(estimate, dtype=float) - np.asarray(twin, dtype=float)
    rows = np.all(np.isfinite(diff), axis=1)
    v_norm = float(np.sqrt(np.sum(v * v)))
    measured = float(np.sqrt(np.sum(diff[rows] ** 2)) / v_norm) if v_norm > 0 else None
    certified, covers = certified_noise_gain(card), gain_covers(card)
    respected = (None if certified is None or measured is None or covers
                 else bool(measured <= certified * (1 + GAIN_RTOL)))
    err = np.asarray(estimate, dtype=float) - np.asarray(true, dtype=float)
    err_twin = np.asarray(twin, dtype=float) - np.asarray(true, dtype=float)
    valid = np.all(np.isfinite(err), axis=1)
    out = {"noise_gain_certified": certified, "noise_gain_measured": measured, "noise_gain_respected": respected,
           "noise_gain_covers": covers,
           "noise_gain_ratio": None if certified in (None, 0.0) or measured is None else measured / certified,
           "noise_std_norm": float(np.linalg.norm(effective)),
           "noise_rms_error": _second_half_rms(err[valid])}
    if dhat is not None and d is not None and np.size(dhat) and len(d) > 1:
        out["noise_dhat_rms_error"] = _second_half_rms(np.asarray(dhat)[1:] - np.asarray(d)[:-1])
    out["noise"] = {"signal": "y", "std": std.tolist(), "seed": None if noise is None else noise.seed,
                    "text": None if noise is None else noise.text(), "quantum": quantum,
                    "effective_std": effective.tolist(), "noise_norm": v_norm,
                    "rms_error_noise_free": _second_half_rms(err_twin[valid]),
                    "bound_checked_on": "the noise-free twin (the certified bound is one of noise-free outputs)"}
    return out


def process_noise_metrics(certified: float | None, error: np.ndarray, twin_error: np.ndarray,
                          w: np.ndarray) -> dict:
    """The metrics of a run with process noise.

    Process noise moves the plant itself, so an observer twin fed the same plant cannot split it off: the
    twin is a whole noise-free loop (a second plant FMU given every input but the noise, a second observer
    fed by it). The error dynamics of a decoupled observer are linear and free of ``x``, ``u`` and ``d``, so
    ``error - twin_error`` is the response of the error to ``w`` alone from a zero initial error (the
    initial-condition term is the twin's), what ``noise.gain_w`` bounds:
    ``noise_gain_w_measured = ||e - e_twin||_2 / ||w||_2``.

    Parameters
    ----------
    certified : float or None
        The card's ``noise.gain_w``.
    error, twin_error : (K+1, .) arrays
        The estimation error of the noisy loop and of its twin (NaN rows, as a functional observer's
        first ones, are left out).
    w : (K, r) array
        The noise held over each step.

    Returns
    -------
    dict
        ``noise_gain_w_certified``, ``noise_gain_w_measured`` (None for ``w = 0``), ``noise_gain_w_respected``
        (measured <= certified (1 + :data:`GAIN_RTOL`); None without a certified gain), ``noise_gain_w_ratio``,
        ``noise_w_std_norm`` (the rms of ``w`` per element, as a norm over the elements) and
        ``noise_w_rms_error`` (the noisy loop's error over the second half of the run, per element).
    """
    diff = np.asarray(error, dtype=float) - np.asarray(twin_error, dtype=float)
    rows = np.all(np.isfinite(diff), axis=1)
    w_norm = float(np.sqrt(np.sum(w * w)))
    measured = float(np.sqrt(np.sum(diff[rows] ** 2)) / w_norm) if w_norm > 0 else None
    respected = None if certified is None or measured is None else bool(measured <= certified * (1 + GAIN_RTOL))
    valid = np.all(np.isfinite(error), axis=1)
    return {"noise_gain_w_certified": certified, "noise_gain_w_measured": measured,
            "noise_gain_w_respected": respected,
            "noise_gain_w_ratio": None if certified in (None, 0.0) or measured is None else measured / certified,
            "noise_w_std_norm": float(np.linalg.norm(np.sqrt(np.mean(w * w, axis=0)))) if len(w) else 0.0,
            "noise_w_rms_error": _second_half_rms(np.asarray(error, dtype=float)[valid])}


__all__ = ["GAIN_RTOL", "Noise", "certified_noise_gain", "noise_metrics", "noises", "parse_noise",
           "process_noise_metrics"]
