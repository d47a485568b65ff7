"""Design robustness on random problems that are not in the papers.

    .venv/bin/python benchmarks/design_robustness.py [--family F] [--count N] [--seed S] [--quick]
                                                     [--timeout T] [--worst K] [--tracebacks K]
                                                     [--reproducers DIR] [--json FILE]
                                                     [--plant-class C] [--e-scale S]

For every problem of :mod:`uiofmu.families.random_plants` (``--count`` per family, default 150; ``--quick``
15; ``--plant-class`` draws one class only; ``--e-scale`` multiplies every unknown-input matrix ``E``, the
same problems in another unit of ``d``: ``--family ltv-auid --plant-class near-limit-zeros --e-scale 1e-10``
is the class of sampled zeros next to the unit circle with a tiny ``E``), in this process, one after the
other:

1. ``uiofmu.check``: does an observer exist?
2. ``uiofmu.design`` with the searched value at ``"max"`` (lti-uio ``decay``, ltv-auid ``mu``,
   sampled-data ``alpha``): certified? which value?
3. When "max" certified a value, a design at each fixed value on its feasible side
   (:func:`uiofmu.families.random_plants.fixed_values`: slower decays for lti-uio, smaller alpha and mu):
   designed, rejected by the re-check (``InfeasibleError`` whose message says the re-check
   refused the point, or a ``CardError``), infeasible (any other ``InfeasibleError``), or another
   error. Every failure there is a **monotonicity violation**: the LMIs at such a value are
   satisfied by the point certified at the max.
4. Every verified card is judged: a **false certificate** is a card marked verified whose
   ``decay_bound`` is 1 or more, whose checks fail when ``uiofmu.verify`` re-runs them, or whose
   certified bound (:func:`uiofmu.families.certified_bound`) is violated in a 200-step
   simulation of the real plant (its exact sampling) and the reference ``Runtime``, with a
   random unknown input, random known input and random initial error; a step violates the
   bound when ``||x_k - xhat_k|| > (1 + 1e-9) b_k + 1e-12 max(1, ||x_k||)``, and the error
   recursion ``e+ = N e`` of the card's own matrices is run alongside. Sampled-data runs draw each
   step from the design intervals. A violation of the plant + runtime run alone is reported as
   "round-off floor only", not counted as a false certificate, when double precision explains it:
   every step's leak (the run's error ``e_{k+1}`` minus the recursion's ``N_k e_k``) is within
   :data:`LEAK_EPS` of the magnitudes that step adds up (``A x``, ``E d``, ``B u``, ``Xz z``,
   ``Xy y``, ``L y``), and the error stays below the bound plus those leaks carried forward by
   the certified decay, ``overshoot * sum_j decay^(k-1-j) ||leak_j||`` (an identity that holds
   to round-off, times a state of 1e4, leaks far more than the bound that falls toward 0).
5. When "max" fails where the check says an observer exists, whether its message names the
   weak mode and its margin (:func:`weak_mode_named`: the largest fixed mode, computed here
   independently of the family code, with its margin ``1 - |z|``, ``1 - |z|^2`` or the family's
   limit from it; or a weakly observable mode, an eigenvalue of a decoupled matrix at a design
   step, with a margin), and whether a design at fixed values derived from that limit succeeds.

An exception that is not a ``UserError`` is an **exit 1** (the command line would exit 1) and a
**traceback**; the first few are printed at the end. A design slower than ``--timeout`` seconds
(default 60) is stopped and counted as a timeout, not as a verdict.

Output: one table per family (each goal with its status), the worst cases (family, seed, name,
what happened, message), tracebacks, and the total time. The exit status is 0 when every goal
holds, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import signal
import sys
import time
import traceback
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import uiofmu  # noqa: E402
from uiofmu.runtime.errors import CardError, InfeasibleError, NoObserverError, UserError  # noqa: E402
from uiofmu.problem import problem_from_data, to_toml  # noqa: E402
from uiofmu.families.random_plants import (CLASSES, FAMILY_CODES, SEARCHED, campaign_draws, fixed_values,  # noqa: E402
                                  with_value)

FAMILIES = tuple(FAMILY_CODES)
#: Relative and absolute slack of the simulated bound (see the module docstring).
BOUND_RTOL, BOUND_FLOOR = 1e-9, 1e-12
#: Simulated steps per verified card.
SIM_STEPS = 200


class DesignTimeout(BaseException):
    """A design took longer than the per-design timeout (BaseException: no library handler
    that catches Exception swallows it)."""


@contextmanager
def time_limit(seconds: float | None):
    """Raise :class:`DesignTimeout` in the block after ``seconds`` (SIGALRM; main thread only)."""
    if not seconds or not hasattr(signal, "setitimer"):
        yield
        return

    def fire(signum, frame):
        raise DesignTimeout(f"stopped after {seconds:g} s")

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# -- outcomes ---------------------------------------------------------------------------------

@dataclass
class Outcome:
    """One call (check or design) and what came of it.

    ``kind``: ``ok``, ``rejected`` (the re-check refused the point, or a CardError),
    ``infeasible``, ``no-observer``, ``other`` (another UserError), ``timeout`` or ``exit1``.
    """

    kind: str
    value: object = None
    message: str = ""
    error: str = ""
    seconds: float = 0.0
    trace: str = ""


def classify(exc: BaseException) -> str:
    """The outcome kind of an exception raised by check or design."""
    if isinstance(exc, DesignTimeout):
        return "timeout"
    if not isinstance(exc, UserError):
        return "exit1"
    text = str(exc)
    if isinstance(exc, CardError) or (isinstance(exc, InfeasibleError) and "re-check" in text):
        return "rejected"
    if isinstance(exc, InfeasibleError):
        return "infeasible"
    if isinstance(exc, NoObserverError):
        return "no-observer"
    return "other"


def call(fn, *args, timeout: float | None = None) -> Outcome:
    """Run ``fn(*args)`` under the time limit and classify what happened."""
    t0 = time.perf_counter()
    try:
        with time_limit(timeout):
            value = fn(*args)
        return Outcome("ok", value, seconds=time.perf_counter() - t0)
    except BaseException as exc:          # noqa: BLE001 - everything is judged, KeyboardInterrupt aside
        if isinstance(exc, KeyboardInterrupt):
            raise
        kind = classify(exc)
        return Outcome(kind, None, str(exc), type(exc).__name__, time.perf_counter() - t0,
                       traceback.format_exc() if kind == "exit1" else "")


def design_doc(doc: dict, timeout: float | None) -> Outcome:
    """Parse and design one document."""
    def run():
        return uiofmu.design(problem_from_data(doc))
    return call(run, timeout=timeout)


# -- the weak mode, computed independently -------------------------------------------------------

def _fixed_modes(A, E, C):
    from uiofmu.structure import unobservable_modes

    M = -E @ np.linalg.pinv(C @ E)
    return unobservable_modes((np.eye(len(A)) + M @ C) @ A, C)


def weak_modes(problem) -> dict:
    """The largest fixed mode(s) and the margins a message may name, without the family code.

    Returns
    -------
    dict
        ``modes``: complex modes that limit the design (largest fixed mode; for ltv-auid also
        that of the transient vertex); ``margins``: positive numbers a message may quote for
        them; ``limit``: the theoretical end of the searched value (decay: the mode's modulus;
        alpha: ``1 - |z|^2``; mu: the mu limit), or None; ``eigenvalues``: every eigenvalue of
        the decoupled matrices ``(I + MC) A`` (and of ``A``) at the design steps, which a message
        may name as a weakly observable mode.
    """
    from uiofmu.structure import unobservable_modes

    plant, opts = problem.plant, problem.options
    C = plant.C
    modes, margins, limit, eigs = [], [], None, []
    try:
        steps = opts.intervals if problem.family == "sampled-data" else (opts.dt,)
        worst = None
        for h in steps:
            s = plant.sampled(h) if plant.continuous else plant.sampled()
            M = -s.E @ np.linalg.pinv(C @ s.E)
            eigs += list(np.linalg.eigvals((np.eye(plant.n) + M @ C) @ s.A)) + list(np.linalg.eigvals(s.A))
            f = _fixed_modes(s.A, s.E, C)
            if f.size and (worst is None or abs(f).max() > abs(worst)):
                worst = f[int(np.argmax(abs(f)))]
        eigs += list(np.linalg.eigvals(plant.A))
        z = float(abs(worst)) if worst is not None else 0.0
        if worst is not None:
            modes.append(complex(worst))
        margins += [1 - z, 1 - z * z]
        limit = 1 - z * z if problem.family == "sampled-data" else z
        if problem.family == "ltv-auid":
            eta, alpha = opts.eta, opts.alpha
            s = plant.sampled()
            M = -s.E @ np.linalg.pinv(C @ s.E)
            A1 = (np.eye(plant.n) + (1 - alpha) * M @ C) @ s.A
            eigs += list(np.linalg.eigvals(A1))
            f1 = unobservable_modes(A1, C)
            z1 = float(abs(f1).max()) if f1.size else 0.0
            if f1.size:
                modes.append(complex(f1[int(np.argmax(abs(f1)))]))
                margins += [1 - z1, 1 - z1 * z1]
            mu_limit = min(1 / eta - 1, (1 - z1 * z1) / eta - 1)
            margins += [1 - z * z - eta, mu_limit, 1 / eta - 1, math.sqrt(max(1 - eta, 0)) - z]
            limit = mu_limit
    except (np.linalg.LinAlgError, ValueError, UserError):
        pass
    return {"modes": modes, "margins": [m for m in margins if m > 0], "limit": limit,
            "eigenvalues": [complex(v) for v in eigs]}


_NUM = r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?"
_NUMBER = re.compile(_NUM)
_MODE = re.compile(rf"modes?(?:\(s\))?\s+({_NUM})(?:\s*±\s*({_NUM})j)?", re.I)
_MARGIN = re.compile(rf"margin[^0-9+\-.;]{{0,24}}({_NUM})", re.I)


#: A sampled-data message that names the intervals without a certificate (alone or in pairs).
_INTERVALS = re.compile(r"the pair\(s\) [0-9.e+-]+ and [0-9.e+-]+ s|interval\(s\) [0-9.e+-]+.* alone have no "
                        r"certificate|no Lyapunov function was found")


def weak_mode_named(message: str, weak: dict) -> str:
    """How ``message`` names the weak mode and its margin: ``"fixed mode"`` (a number equal to
    the modulus, real or imaginary part of the largest fixed mode, to 1e-4 relative, one within
    10 % of its margin, and the word "mode" or "zero"), ``"weakly observable mode"`` ("mode X"
    with X an eigenvalue of a decoupled matrix at a design step, to 1e-5 relative, and
    "margin Y"), or ``""`` (neither)."""
    numbers = [float(t) for t in _NUMBER.findall(message)]
    numbers = [x for x in numbers if math.isfinite(x)]

    def close(x, v, rtol):
        return v != 0 and abs(abs(x) - abs(v)) <= rtol * abs(v)

    if weak.get("modes") and re.search(r"mode|zero", message, re.I):
        named = [i for i, x in enumerate(numbers)
                 if any(close(x, v, 1e-4) for m in weak["modes"] for v in (abs(m), m.real, m.imag))]
        margin = [i for i, x in enumerate(numbers) if any(close(x, v, 0.1) for v in weak["margins"])]
        if named and any(j not in named or len(named) > 1 for j in margin):
            return "fixed mode"
    eigs = weak.get("eigenvalues") or []
    if eigs and _MARGIN.search(message):
        scale = max(abs(v) for v in eigs)
        for m in _MODE.finditer(message):
            v = complex(float(m.group(1)), float(m.group(2) or 0.0))
            if any(min(abs(v - e), abs(v - e.conjugate())) <= 1e-5 * abs(e) + 1e-9 * scale for e in eigs):
                return "weakly observable mode"
    return ""


def names_weak_mode(message: str, weak: dict) -> bool:
    """Whether ``message`` names a weak mode and its margin (see :func:`weak_mode_named`)."""
    return bool(weak_mode_named(message, weak))


# -- simulation --------------------------------------------------------------------------------

#: A step's leak counts as round-off when it is at most this fraction of the magnitudes the
#: step adds up (``||A|| ||x||``, ``||E|| ||d||``, ``||B|| ||u||``, ``||Xz|| ||z||``,
#: ``||Xy|| ||y||``, ``||L|| ||y||``): about 4500 times the machine epsilon.
LEAK_EPS = 1e-12


def _gain(card, key: str) -> float:
    """The largest Frobenius norm of the card's matrix ``key`` over its schedule axes (summed
    over the polynomial coefficients of a geometric schedule)."""
    arr = np.asarray(card.data["matrices"][key], dtype=float)
    if arr.ndim <= 2:
        return float(np.linalg.norm(arr))
    slices = np.sqrt(np.sum(arr.reshape(-1, *arr.shape[-2:]) ** 2, axis=(-2, -1)))
    return float(slices.sum() if card.schedule.get("kind") == "geometric" else slices.max())


def simulate(card, problem, rng, steps: int = SIM_STEPS) -> dict:
    """The real plant and the reference runtime over ``steps`` steps against the certified bound.

    Returns
    -------
    dict
        ``violated`` (bool, by the rule of the module docstring, in the plant + runtime run or
        in the error recursion), ``recursion`` (the error recursion ``e_{k+1} = N_k e_k + S_k d_k``
        with the card's own ``N`` from its schedule, ``S_k = -alpha^{k+1} M C E`` for ltv-auid
        and 0 otherwise, violates the bound: the certificate itself is wrong), ``roundoff`` (only
        the plant + runtime run violates it, every step leaks within :data:`LEAK_EPS` of its
        magnitudes, and the error stays under the bound plus the leaks carried forward),
        ``worst_leak`` (largest leak over magnitude), ``worst_ratio``
        (largest ``||e_k|| / allowance_k``), ``at`` (the first violating step with its numbers),
        ``bound`` None when the card certifies none.
    """
    from uiofmu.families import certified_bound
    from uiofmu.runtime.observer import Runtime
    from uiofmu.runtime.schedules import make_schedule

    plant = problem.plant
    n, q, m = plant.n, plant.q, plant.m
    intervals = card.data.get("intervals")
    hs = (rng.choice(np.asarray(intervals, dtype=float), size=steps) if intervals else
          np.full(steps, float(card.data["dt"])))
    gz, gy = _gain(card, "Xz"), max(_gain(card, "Xy"), _gain(card, "L"))
    x = rng.normal(size=n)
    e0 = rng.normal(size=n)
    xhat0 = x - e0
    d = np.zeros((steps + 1, q))
    u = np.zeros((steps + 1, m))
    rt = Runtime(card, xhat0=xhat0)
    sched = make_schedule(card.schedule, card.matrices)
    S = None
    if card.family == "ltv-auid":                      # S_k = -alpha^(k+1) M C E
        mats = card.data["matrices"]
        S = -np.asarray(mats["M"]) @ np.asarray(mats["C"]) @ np.asarray(mats["E_sampled"])
    e, h_prev = e0.copy(), rt.h_prev0
    rec = np.empty(steps + 1)
    err = np.empty(steps + 1)
    xn = np.empty(steps + 1)
    inner = np.empty(steps + 1)
    leak = np.zeros(steps + 1)              # leak[k + 1]: what step k added beyond N_k e_k
    magnitude = np.ones(steps + 1)
    real_prev = None
    for k in range(steps + 1):
        h = float(hs[k]) if k < steps else float(hs[-1])
        s = plant.sampled(h) if plant.continuous else plant.sampled()
        d[k] = rng.normal(size=q) / max(float(np.linalg.norm(s.E, 2)), 1e-300)
        if m:
            u[k] = rng.normal(size=m) / max(float(np.linalg.norm(s.B, 2)), 1e-300)
        y = plant.C @ x
        rt.set_y(y)
        rt.set_u(u[k])
        real = x - rt.xhat()
        err[k] = float(np.linalg.norm(real))
        xn[k] = float(np.linalg.norm(x))
        inner[k] = max(xn[k], gz * float(np.linalg.norm(rt.z)), gy * float(np.linalg.norm(y)))
        rec[k] = float(np.linalg.norm(e))
        if real_prev is not None:
            leak[k] = float(np.linalg.norm(real - real_prev))
            magnitude[k] = max(magnitude[k], inner[k])
        if k == steps:
            break
        rt.step(h)
        Nk = sched.step_matrices(k, h, h_prev)["N"]
        magnitude[k + 1] = max(1.0, inner[k], float(np.linalg.norm(s.A, 2)) * xn[k],
                               float(np.linalg.norm(s.E @ d[k])), float(np.linalg.norm(s.B @ u[k])))
        x = s.A @ x + s.B @ u[k] + s.E @ d[k] + s.w
        real_prev = Nk @ real                          # the recursion's step from the run's own error
        e = Nk @ e
        if S is not None:
            e = e + card.data["alpha"] ** (k + 1) * (S @ d[k])
            real_prev = real_prev + card.data["alpha"] ** (k + 1) * (S @ d[k])
        h_prev = h
    bound = certified_bound(card, e0, d)
    if bound is None:
        return {"violated": False, "roundoff": False, "recursion": False, "worst_ratio": None, "at": None,
                "bound": None}
    allow = (1 + BOUND_RTOL) * bound + BOUND_FLOOR * np.maximum(1.0, xn)
    ratio = err / allow
    bad = np.flatnonzero(ratio > 1.0)
    rec_bad = np.flatnonzero(rec > allow)
    at = None
    carried = np.zeros(steps + 1)           # overshoot * sum_j decay^(k-1-j) ||leak_j||
    over, decay = float(card.data.get("overshoot_bound") or 1.0), float(card.data.get("decay_bound") or 1.0)
    for k in range(1, steps + 1):
        carried[k] = decay * carried[k - 1] + over * leak[k]
    worst_leak = float((leak / magnitude).max())
    roundoff = (bool(bad.size) and not rec_bad.size and worst_leak <= LEAK_EPS
                and bool(np.all(err[bad] <= allow[bad] + (1 + BOUND_RTOL) * carried[bad])))
    first = bad if bad.size else rec_bad
    if first.size:
        k = int(first[0])
        at = {"k": k, "error": float(err[k]), "recursion": float(rec[k]), "bound": float(bound[k]),
              "x_norm": float(xn[k]), "inner": float(inner[k]), "e0": float(np.linalg.norm(e0)),
              "carried": float(carried[k]), "worst_leak": worst_leak}
    return {"violated": bool(bad.size or rec_bad.size), "roundoff": roundoff, "recursion": bool(rec_bad.size),
            "worst_leak": worst_leak,
            "worst_ratio": float(ratio.max()), "worst_recursion_ratio": float((rec / allow).max()), "at": at,
            "bound": True}


def judge_card(card, problem, rng) -> list[tuple[str, str]]:
    """Why a verified card is a false certificate: ``(tag, text)`` pairs, empty for none. Tags:
    ``bound >= 1``, ``verify``, ``simulation (error recursion)`` (the card's own error recursion
    leaves the bound), ``simulation`` (the plant + runtime run leaves it by more than round-off)
    and ``simulation (round-off)`` (only the plant + runtime run, by leaks within
    :data:`LEAK_EPS` of each step's magnitudes, carried forward; see :func:`simulate`)."""
    reasons = []
    data = card.data
    if not data.get("certificate", {}).get("verified"):
        return [("verify", "card not marked verified")]
    bound = data.get("decay_bound")
    if bound is not None and not bound < 1:
        reasons.append(("bound >= 1", f"decay_bound = {bound!r} >= 1"))
    try:
        failed = [c for c in uiofmu.verify(card) if not c.holds]
        if failed:
            reasons.append(("verify", "uiofmu.verify fails: " + "; ".join(
                f"{c.name} = {c.value:.3g} vs {c.bound:.3g}" for c in failed)))
    except Exception as exc:             # noqa: BLE001
        reasons.append(("verify", f"uiofmu.verify raised {type(exc).__name__}: {exc}"))
    try:
        sim = simulate(card, problem, rng)
        if sim["violated"]:
            a = sim["at"]
            tag = ("simulation (error recursion)" if sim["recursion"] else
                   "simulation (round-off)" if sim["roundoff"] else "simulation")
            reasons.append((tag, f"bound violated in simulation ({tag}) at k = {a['k']}: ||e|| = {a['error']:.6g} "
                                 f"(recursion {a['recursion']:.6g}) > bound "
                                 f"{a['bound']:.6g} (||x|| = {a['x_norm']:.3g}, internal magnitude "
                                 f"{a['inner']:.3g}, leaks carried forward {a['carried']:.3g}, worst leak "
                                 f"{a['worst_leak']:.3g} of a step's magnitude, ||e0|| = {a['e0']:.3g}, "
                                 f"worst ratio {sim['worst_ratio']:.6g}, "
                                 f"decay_bound {data.get('decay_bound')!r}, "
                                 f"overshoot {data.get('overshoot_bound')!r})"))
    except Exception as exc:             # noqa: BLE001
        reasons.append(("simulation", f"simulation raised {type(exc).__name__}: {exc}"))
    return reasons


# -- one problem -------------------------------------------------------------------------------

@dataclass
class Result:
    """Everything measured on one problem."""

    family: str
    seed: int
    name: str
    plant_class: str
    expect_exists: object
    doc: dict
    check: str = ""                      # "exists", "none", or the outcome kind of a failing check
    check_message: str = ""
    max: Outcome | None = None
    found: float | None = None
    fixed: list = field(default_factory=list)        # (value, Outcome)
    fallback: list = field(default_factory=list)     # (value, Outcome) when "max" failed
    false_certificates: list = field(default_factory=list)   # (what, reasons)
    names_weak: bool | None = None
    weak_kind: str = ""
    weak: dict = field(default_factory=dict)
    exits1: list = field(default_factory=list)       # (stage, Outcome)
    disagree: str = ""
    seconds: float = 0.0


def searched_value(card) -> float:
    """The value the card certified for the family's searched key."""
    return float(card.data[SEARCHED[card.family]])


def run_problem(rp, timeout: float | None = 60.0) -> Result:
    """Check, design at "max", at the fixed values, judge every card (see the module docstring)."""
    t0 = time.perf_counter()
    res = Result(rp.family, rp.seed, rp.name, rp.plant_class, rp.expect_exists, rp.doc)
    rng = np.random.default_rng([rp.seed, FAMILY_CODES[rp.family], 7])
    parsed = call(problem_from_data, rp.doc)
    if parsed.kind != "ok":
        res.check, res.check_message = f"problem {parsed.kind}", parsed.message
        if parsed.kind == "exit1":
            res.exits1.append(("problem", parsed))
        res.seconds = time.perf_counter() - t0
        return res
    problem = parsed.value
    chk = call(uiofmu.check, problem, timeout=timeout)
    if chk.kind == "ok":
        res.check = "exists" if chk.value.exists else "none"
        res.check_message = "; ".join(c.message for c in chk.value.failures)
    else:
        res.check, res.check_message = f"check {chk.kind}", chk.message
        if chk.kind == "exit1":
            res.exits1.append(("check", chk))

    def judged(what, out):
        if out.kind == "exit1":
            res.exits1.append((what, out))
        if out.kind == "ok":
            reasons = judge_card(out.value, problem, rng)
            if reasons:
                res.false_certificates.append((what, reasons))
        return out

    res.max = judged("max", design_doc(rp.doc, timeout))
    if res.max.kind == "ok":
        res.found = searched_value(res.max.value)
        if res.check == "none":
            res.disagree = "check says no observer exists, design at max certified one"
        for v in fixed_values(rp.family, res.found, rp.fractions):
            res.fixed.append((v, judged(f"fixed {SEARCHED[rp.family]} = {v:.9g}", design_doc(with_value(rp.doc, v),
                                                                                          timeout))))
    elif res.check == "exists":
        res.weak = weak_modes(problem)
        res.weak_kind = weak_mode_named(res.max.message, res.weak)
        res.names_weak = bool(res.weak_kind)
        limit = res.weak.get("limit")
        if limit is not None and math.isfinite(limit) and (rp.family == "lti-uio" or limit > 0):
            for v in fixed_values(rp.family, limit, rp.fractions):
                res.fallback.append((v, judged(f"theory-side {SEARCHED[rp.family]} = {v:.9g}",
                                               design_doc(with_value(rp.doc, v), timeout))))
    res.seconds = time.perf_counter() - t0
    return res


# -- summary -----------------------------------------------------------------------------------

def summarise(results: list[Result]) -> dict:
    """The per-family counts of the table."""
    c = Counter()
    for r in results:
        c["problems"] += 1
        c["check exists"] += r.check == "exists"
        c["check none"] += r.check == "none"
        c["check none, built to exist"] += r.check == "none" and r.expect_exists is True
        c["check error"] += r.check.startswith(("check ", "problem "))
        if r.max is not None:
            c["max certified"] += r.max.kind == "ok"
            c["max certified, check exists"] += r.max.kind == "ok" and r.check == "exists"
            if r.check == "exists" and r.max.kind != "ok":
                c["max failed, check exists"] += 1
                c["... message names weak mode"] += bool(r.names_weak)
                c["... ... a fixed mode + its margin"] += r.weak_kind == "fixed mode"
                c["... ... a weakly observable mode + PBH margin"] += r.weak_kind == "weakly observable mode"
                c["... message names the intervals that fail together"] += bool(_INTERVALS.search(r.max.message))
                c[f"... max {r.max.kind}"] += 1
            c["max timeout"] += r.max.kind == "timeout"
        for _, o in r.fixed:
            c["fixed tried"] += 1
            c["fixed designed"] += o.kind == "ok"
            c["fixed rejected"] += o.kind == "rejected"
            c["fixed infeasible"] += o.kind == "infeasible"
            c["fixed other error"] += o.kind in ("other", "no-observer")
            c["fixed timeout"] += o.kind == "timeout"
            c["fixed exit 1"] += o.kind == "exit1"
            c["monotonicity violations"] += o.kind not in ("ok", "timeout")
        for _, o in r.fallback:
            c["theory-side tried (max failed)"] += 1
            c["theory-side designed (max failed)"] += o.kind == "ok"
        counted = sum(not roundoff_only(reasons) for _, reasons in r.false_certificates)
        c["false certificates"] += counted
        c["round-off floor only (not counted)"] += len(r.false_certificates) - counted
        c["... bound >= 1"] += sum(any(t == "bound >= 1" for t, _ in rs) for _, rs in r.false_certificates)
        c["... verify fails"] += sum(any(t == "verify" for t, _ in rs) for _, rs in r.false_certificates)
        c["... error recursion leaves the bound"] += sum(any(t == "simulation (error recursion)" for t, _ in rs)
                                                        for _, rs in r.false_certificates)
        c["... runtime leaves it beyond round-off"] += sum(any(t == "simulation" for t, _ in rs)
                                                          for _, rs in r.false_certificates)
        c["problems with a false certificate"] += counted > 0
        c["problems with a round-off floor run (not counted)"] += len(r.false_certificates) > counted
        c["exits 1"] += len(r.exits1)
        c["tracebacks"] += len(r.exits1)
        c["check/design disagree"] += bool(r.disagree)
        c["seconds"] += r.seconds
    return c


def roundoff_only(reasons) -> bool:
    """Whether a verified card's reasons are all a run at double precision's floor (not a false certificate)."""
    return all(tag == "simulation (round-off)" for tag, _ in reasons)


def _pct(a, b):
    return f"{100.0 * a / b:.1f} %" if b else "-"


def goals(c: Counter) -> list[tuple[str, str, bool]]:
    """(goal, measured, holds) for one family's counts."""
    exists = c["check exists"]
    certified = c["max certified, check exists"]
    failed = c["max failed, check exists"]
    named = c["... message names weak mode"]
    return [
        ("0 false certificates", f"{c['false certificates']} (and {c['round-off floor only (not counted)']} at the "
         "round-off floor)", c["false certificates"] == 0),
        ("0 monotonicity violations", str(c["monotonicity violations"]), c["monotonicity violations"] == 0),
        (">= 99 % of fixed values below max designed",
         f"{c['fixed designed']}/{c['fixed tried']} = {_pct(c['fixed designed'], c['fixed tried'])}",
         c["fixed tried"] == 0 or c["fixed designed"] >= 0.99 * c["fixed tried"]),
        (">= 99 % of exists: max certifies", f"{certified}/{exists} = {_pct(certified, exists)}",
         exists == 0 or certified >= 0.99 * exists),
        ("rest: message names weak mode + margin", f"{named}/{failed}", named == failed),
        ("0 exits 1", str(c["exits 1"]), c["exits 1"] == 0),
        ("0 tracebacks", str(c["tracebacks"]), c["tracebacks"] == 0),
    ]


ROWS = ["problems", "check exists", "check none", "check none, built to exist", "check error", "max certified",
        "max certified, check exists", "max failed, check exists", "... message names weak mode",
        "... ... a fixed mode + its margin", "... ... a weakly observable mode + PBH margin",
        "... message names the intervals that fail together", "... max rejected", "... max infeasible",
        "... max other", "... max timeout", "... max exit1",
        "fixed tried", "fixed designed", "fixed rejected", "fixed infeasible", "fixed other error", "fixed timeout",
        "fixed exit 1", "monotonicity violations", "theory-side tried (max failed)",
        "theory-side designed (max failed)", "false certificates", "... bound >= 1", "... verify fails",
        "... error recursion leaves the bound", "... runtime leaves it beyond round-off",
        "round-off floor only (not counted)", "problems with a false certificate",
        "problems with a round-off floor run (not counted)",
        "check/design disagree", "exits 1", "tracebacks"]


def table(family: str, c: Counter) -> str:
    """One family's table: counts, then the goals with their status."""
    lines = [f"== {family}: {c['problems']} problems, {c['seconds']:.1f} s ==",
             f"  {'measure':46s} {'count':>22s}"]
    lines += [f"  {k:46s} {c[k]:22d}" for k in ROWS
              if k in ("problems", "fixed tried") or c[k] or not k.startswith("...")]
    lines.append(f"  {'goal':46s} {'measured':>22s}  status")
    lines += [f"  {g:46s} {m:>22s}  {'ok' if ok else 'FAIL'}" for g, m, ok in goals(c)]
    return "\n".join(lines)


SEVERITY = ("false certificate", "exit 1", "monotonicity violation", "max failed, weak mode not named",
            "max failed, weak mode named (fixed mode)", "max failed, weak mode named (weakly observable mode)",
            "false certificate (round-off floor)", "check/design disagree",
            "check none, built to exist", "timeout")


def cases(r: Result) -> list[tuple[str, str]]:
    """(what happened, message) for the notable events of one problem, by severity."""
    out = []
    for what, reasons in r.false_certificates:
        out.append(("false certificate (round-off floor)" if roundoff_only(reasons) else "false certificate",
                    f"{what}: {'; '.join(text for _, text in reasons)}"))
    for stage, o in r.exits1:
        out.append(("exit 1", f"{stage}: {o.error}: {o.message}"))
    for v, o in r.fixed:
        if o.kind not in ("ok", "timeout", "exit1"):
            out.append(("monotonicity violation", f"{SEARCHED[r.family]} = {v:.9g} ({o.kind}, max certified "
                                                  f"{r.found:.9g}): {o.error}: {o.message}"))
    if r.check == "exists" and r.max is not None and r.max.kind not in ("ok", "exit1"):
        mode = ", ".join(f"{abs(m):.9g}" for m in r.weak.get("modes", [])) or "none"
        fb = sum(o.kind == "ok" for _, o in r.fallback)
        what = f"max failed, weak mode named ({r.weak_kind})" if r.names_weak else "max failed, weak mode not named"
        out.append((what, f"{r.max.kind} (largest fixed mode modulus {mode}; theory-side designs "
                          f"{fb}/{len(r.fallback)}): {r.max.error}: {r.max.message}"))
    if r.disagree:
        out.append(("check/design disagree", r.disagree))
    if r.check == "none" and r.expect_exists is True:
        out.append(("check none, built to exist", r.check_message))
    for label, o in [("max", r.max)] + [(f"{SEARCHED[r.family]} = {v:.6g}", o) for v, o in r.fixed]:
        if o is not None and o.kind == "timeout":
            out.append(("timeout", f"{label}: {o.message}"))
    return out


def worst_cases(results: list[Result], limit: int) -> list[tuple]:
    """The notable events of all problems, most severe first."""
    rows = [(SEVERITY.index(what), r.family, r.seed, r.name, what, msg) for r in results for what, msg in cases(r)]
    rows.sort(key=lambda t: (t[0], t[1], t[2]))
    return rows[:limit] if limit >= 0 else rows


def _short(text: str, limit: int = 400) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit] + " ..."


def result_data(r: Result) -> dict:
    """JSON-ready form of one result (for ``--json``)."""
    def o(x):
        return None if x is None else {"kind": x.kind, "message": x.message, "error": x.error,
                                       "seconds": x.seconds}
    return {"family": r.family, "seed": r.seed, "name": r.name, "class": r.plant_class, "check": r.check,
            "check_message": r.check_message, "max": o(r.max), "found": r.found,
            "fixed": [{"value": v, **o(x)} for v, x in r.fixed],
            "fallback": [{"value": v, **o(x)} for v, x in r.fallback],
            "false_certificates": r.false_certificates, "names_weak": r.names_weak, "weak_kind": r.weak_kind,
            "weak": {"modes": [[m.real, m.imag] for m in r.weak.get("modes", [])],
                     "margins": r.weak.get("margins", []), "limit": r.weak.get("limit")},
            "exits1": [(s, x.error, x.message) for s, x in r.exits1], "seconds": r.seconds,
            "cases": cases(r)}


def with_unknown_input_scaled(rp, scale: float):
    """``rp`` with its unknown-input matrix ``E`` (every mode's too) multiplied by ``scale``: the same observer
    problem in another unit of ``d``, which no certificate's existence depends on."""
    import copy
    from dataclasses import replace

    doc = copy.deepcopy(rp.doc)
    for table in [doc["plant"], *doc["plant"].get("modes", [])]:
        if "E" in table:
            table["E"] = (np.asarray(table["E"], dtype=float) * scale).tolist()
    return replace(rp, doc=doc)


def run_campaign(families, count: int, seed: int, timeout: float | None, progress=None, e_scale: float = 1.0,
                 **knobs) -> dict:
    """Every family's results: ``{family: [Result, ...]}`` (``e_scale``: :func:`with_unknown_input_scaled`)."""
    out = {}
    for family in families:
        out[family] = []
        for i, rp in enumerate(campaign_draws(family, count, seed, **knobs)):
            r = run_problem(rp if e_scale == 1.0 else with_unknown_input_scaled(rp, e_scale), timeout)
            out[family].append(r)
            if progress:
                progress(family, i, count, r)
    return out


def main(argv=None) -> int:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--family", choices=FAMILIES, action="append", help="only this family (repeatable)")
    ap.add_argument("--count", type=int, default=None, help="problems per family (default 150; --quick 15)")
    ap.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    ap.add_argument("--quick", action="store_true", help="15 problems per family")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per design before it is stopped (60)")
    ap.add_argument("--worst", type=int, default=40, help="worst cases listed (default 40; -1 all)")
    ap.add_argument("--tracebacks", type=int, default=3, help="tracebacks printed (default 3)")
    ap.add_argument("--reproducers", type=Path, help="write each listed worst case's problem as TOML here")
    ap.add_argument("--json", type=Path, help="write every result as JSON here")
    ap.add_argument("--verbose", action="store_true", help="one line per problem on stderr")
    ap.add_argument("--plant-class", choices=CLASSES, help="draw only plants of this class (e.g. near-limit-zeros)")
    ap.add_argument("--e-scale", type=float, default=1.0,
                    help="multiply every unknown-input matrix E by this (e.g. 1e-10: the same problems in another "
                         "unit of d; default 1)")
    args = ap.parse_args(argv)
    count = args.count if args.count is not None else (15 if args.quick else 150)
    families = args.family or list(FAMILIES)

    def progress(family, i, total, r):
        if args.verbose:
            mx = r.max.kind if r.max else "-"
            print(f"  {family} {i + 1}/{total} seed {r.seed} {r.plant_class}: check {r.check}, max {mx}"
                  f"{'' if r.found is None else f' {r.found:.6g}'}, fixed "
                  f"{sum(o.kind == 'ok' for _, o in r.fixed)}/{len(r.fixed)}, {r.seconds:.2f} s",
                  file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    knobs = {"plant_class": args.plant_class} if args.plant_class else {}
    results = run_campaign(families, count, args.seed, args.timeout, progress, e_scale=args.e_scale, **knobs)
    total = time.perf_counter() - t0
    ok = True
    print(f"design robustness: {count} problems per family, campaign seed {args.seed}, "
          f"timeout {args.timeout:g} s per design")
    for family in families:
        c = summarise(results[family])
        print()
        print(table(family, c))
        ok &= all(g[2] for g in goals(c))
    everything = [r for family in families for r in results[family]]
    worst = worst_cases(everything, args.worst)
    print()
    print(f"worst cases ({len(worst)} listed of {len(worst_cases(everything, -1))}):")
    for _, family, seed, name, what, msg in worst:
        print(f"  [{what}] {family} seed {seed} {name}\n      {_short(msg)}")
    if args.reproducers and worst:
        args.reproducers.mkdir(parents=True, exist_ok=True)
        byname = {r.name: r for r in everything}
        for _, family, seed, name, what, msg in worst:
            r = byname[name]
            header = (f"{what}: {family} seed {seed} "
                      f"(uiofmu.families.random_plants.random_problem({family!r}, {seed}))\n"
                      f"{_short(msg, 2000)}")
            (args.reproducers / f"{name}.toml").write_text(to_toml(r.doc, header))
    traces = [(r, stage, o) for r in everything for stage, o in r.exits1]
    if traces:
        print()
        print(f"tracebacks (first {min(args.tracebacks, len(traces))} of {len(traces)}):")
        for r, stage, o in traces[: args.tracebacks]:
            print(f"--- {r.family} seed {r.seed} {r.name} ({stage})")
            print(o.trace.rstrip())
    if args.json:
        args.json.write_text(json.dumps({f: [result_data(r) for r in results[f]] for f in families}, indent=1,
                                        default=str))
    print()
    per = ", ".join(f"{f} {summarise(results[f])['seconds']:.1f} s" for f in families)
    print(f"total time {total:.1f} s ({per})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
