"""The co-simulation summary a person reads first (``uiofmu cosim``, ``uiofmu demo``, a campaign's
replayed row): what the run measured against what the design certified, and where the files are.
"""

from __future__ import annotations

import sys


def print_summary(metrics: dict, paths: dict | None = None, file=None) -> None:
    """The co-simulation summary a person reads first."""
    file = file or sys.stdout
    p = lambda *a: print(*a, file=file)  # noqa: E731
    if "steps_to_exact" in metrics:
        p(f"  steps                {metrics['steps']} (h = {metrics['step_min']:g} s)")
        p(f"  formula              {metrics.get('formula', '')}")
        p(f"  window               {metrics['window']} outputs, gx is G x of {metrics['delay']} step(s) back, "
          f"valid from step {metrics['valid_from']}")
        exact = metrics["steps_to_exact"]
        p(f"  exact from step      {exact if exact is not None else 'never'}"
          + (" (the first full window)" if metrics["exact_from_first_full_window"] else ""))
        if metrics["max_relative_error_when_valid"] is not None:
            p(f"  largest error        {metrics['max_relative_error_when_valid']:.3g} relative, once valid")
        if "noise" in metrics:
            _print_noise(metrics, p)
        for key, path in (paths or {}).items():
            p(f"  {key:20s} {path}")
        return
    p(f"  steps                {metrics['steps']} (h from {metrics['step_min']:g} to {metrics['step_max']:g} s, "
      f"t_end = {metrics['t_end']:g} s)")
    p(f"  initial error        {metrics['initial_error_norm']:.6g}")
    p(f"  final error          {metrics['final_error_norm']:.6g}")
    k = metrics["steps_to_1pct"]
    p(f"  steps to 1 %         {k if k is not None else 'not reached'}"
      + (f" (t = {metrics['time_to_1pct']:g} s)" if k is not None else ""))
    if "bound_respected" in metrics:
        p(f"  certified bound      {metrics.get('bound_formula')}")
        p(f"                       decay {metrics['certified_decay']:.6g} per step, overshoot "
          f"{metrics['certified_overshoot']:.4g}")
        if metrics["bound_respected"]:
            p(f"  bound respected      yes at every step (largest ratio {metrics['max_bound_ratio']:.4g})")
            if metrics.get("points_on_floor"):
                p(f"                       checked ||e_k|| <= bound_k (1 + {metrics['bound_rtol']:g}) + "
                  f"{metrics['bound_floor']:.3g} ({_floor_words(metrics)}): above the "
                  f"bound itself at {metrics['points_on_floor']} of {metrics['steps'] + 1} points, under the floor")
        else:
            p(f"  bound respected      NO: first at step {metrics['first_bound_violation']}, error "
              f"{metrics['error_at_first_violation']:.3g} > bound {metrics['bound_at_first_violation']:.3g}; the error "
              f"settles at {metrics['error_floor']:.3g} ({_why_not(metrics)})")
    if "dhat_rms_error" in metrics:
        p("  dhat rms error       " + ", ".join(f"{v:.4g}" for v in metrics["dhat_rms_error_second_half"])
          + " (second half of the run)")
    if "noise" in metrics:
        _print_noise(metrics, p)
    if "validity" in metrics:                      # a delayed observer with parameter identification
        _print_delayed(metrics, p)
    for key, path in (paths or {}).items():
        p(f"  {key:20s} {path}")


def _floor_words(metrics: dict) -> str:
    """What the bound check's floor is made of, in words."""
    words = f"round-off floor, {metrics['bound_rtol']:g} ||e_0||"
    leaks = metrics.get("roundoff_floor")
    if leaks and leaks["roundoff"] and leaks["carried"] > 0:
        words += (f" + the leaks of each step (at most {leaks['worst_leak']:.2g} of its magnitudes) carried by the "
                  f"certified decay, {leaks['carried']:.3g}")
    return words


def _why_not(metrics: dict) -> str:
    """Why a bound may fail, by what the run knows of its plant: a plant other than the design model has a
    mismatch floor; the design's own plant does not, and its leaks say whether round-off explains the run."""
    plant = metrics.get("plant")
    if isinstance(plant, dict) and plant.get("mismatch"):
        return (f"the plant FMU's A, B, E are perturbed by a relative mismatch of {plant['mismatch']:.3g}: a model "
                "mismatch, which has a mismatch floor")
    if not (isinstance(plant, dict) and plant.get("is_design_model")):
        return "a plant other than the design model has a mismatch floor"
    leaks = metrics.get("roundoff_floor")
    if leaks is None:
        return "the plant FMU is the design's own model: this is no model mismatch"
    return (f"the plant FMU is the design's own model, so no model mismatch; its steps leak up to "
            f"{leaks['worst_leak']:.2g} of their magnitudes, above round-off's {leaks['leak_eps']:g}")


def _print_noise(metrics: dict, p) -> None:
    """The lines of :func:`print_summary` for a run with noise: the measured noise gain against the certified
    one (a false certificate loudly), the error with noise."""
    nz = metrics["noise"]
    if "std" in nz:
        if nz.get("text"):
            p(f"  noise                {nz['text']} (white, std per output "
              + ", ".join(f"{s:.3g}" for s in nz["std"]) + ", added between the plant and the observer)")
        if nz.get("quantum"):
            p(f"  quantization         outputs rounded to multiples of {nz['quantum']:.6g} on their way to the "
              "observer")
        measured, certified = metrics["noise_gain_measured"], metrics["noise_gain_certified"]
        shown = "none" if measured is None else f"{measured:.4g}"
        if certified is None:
            p(f"  noise gain           measured {shown} (||e - e_twin|| / ||v||); the card certifies none")
        elif metrics.get("noise_gain_covers"):
            p(f"  noise gain           measured {shown} (||e - e_twin|| / ||v||, ratio "
              f"{metrics['noise_gain_ratio']:.3g} to the card's {certified:.4g}); not a check of it: the card's gain "
              "holds with the premises noise-free (noise.covers), and this observer reads the noisy y into them")
        elif metrics["noise_gain_respected"]:
            p(f"  noise gain           measured {shown} <= certified {certified:.4g}: respected "
              f"(ratio {metrics['noise_gain_ratio']:.3g})")
        else:
            p(f"  noise gain           FALSE CERTIFICATE: measured {shown} > certified {certified:.4g} "
              f"(ratio {metrics['noise_gain_ratio']:.3g}): the card's noise.gain_y does not hold")
        p("  rms error with noise " + ", ".join(f"{v:.4g}" for v in metrics["noise_rms_error"])
          + " (second half; noise-free twin " + ", ".join(f"{v:.3g}" for v in nz["rms_error_noise_free"]) + ")")
    if "w" in nz:
        p(f"  process noise        {nz['w']['text']} (white, std per column of W "
          + ", ".join(f"{s:.3g}" for s in nz["w"]["std"]) + ", into the plant FMU's w_noise)")
        measured, certified = metrics["noise_gain_w_measured"], metrics["noise_gain_w_certified"]
        shown = "none" if measured is None else f"{measured:.4g}"
        if certified is None:
            p(f"  process noise gain   measured {shown} (||e - e_twin|| / ||w||, the twin a noise-free loop); the "
              "card certifies none")
        elif metrics["noise_gain_w_respected"]:
            p(f"  process noise gain   measured {shown} <= certified {certified:.4g}: respected "
              f"(ratio {metrics['noise_gain_w_ratio']:.3g})")
        else:
            p(f"  process noise gain   FALSE CERTIFICATE: measured {shown} > certified {certified:.4g} "
              f"(ratio {metrics['noise_gain_w_ratio']:.3g}): the card's noise.gain_w does not hold")


def _print_delayed(metrics: dict, p) -> None:
    """The lines of :func:`print_summary` for a delayed observer: validity, theta, no certified bound."""
    v = metrics["validity"]
    first = f"from t = {v['first_valid_time']:g} s" if v["first_valid_time"] is not None else "never valid"
    p(f"  valid                {100 * v['fraction']:.1f} % of the run ({first}; {v['invalid_stretches']} invalid "
      f"stretch(es) after it; premise bound sigma_min >= {v['sigma_bound']:.3g})")
    s = metrics.get("state_from_first_valid")
    if s is not None:
        at = f"t = {s['time_to_1pct']:g} s" if s["time_to_1pct"] is not None else "not reached"
        p(f"  state error          {s['error_norm']:.4g} at the first valid point; 1 % of it: {at}")
    th = metrics.get("theta")
    if th is not None:
        at = f"t = {th['time_to_1pct']:g} s" if th["time_to_1pct"] is not None else "not reached"
        p("  thetahat             " + ", ".join(f"{x:.6g}" for x in th["final"]) + " (true "
          + ", ".join(f"{x:.6g}" for x in th["true"]) + ", from the plant FMU)")
        p(f"  theta error          final {th['final_error_norm']:.3g} ({th['final_relative_error']:.3g} relative); "
          f"within 1 % of |theta| while valid: {at}")
    p("  certified bound      none compared: it holds on the premise set only")


__all__ = ["print_summary"]
