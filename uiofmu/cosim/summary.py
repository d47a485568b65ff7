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
                  f"{metrics['bound_floor']:.3g} (round-off floor, {metrics['bound_rtol']:g} ||e_0||): above the "
                  f"bound itself at {metrics['points_on_floor']} of {metrics['steps'] + 1} points, under the floor")
        else:
            p(f"  bound respected      NO: first at step {metrics['first_bound_violation']}, error "
              f"{metrics['error_at_first_violation']:.3g} > bound {metrics['bound_at_first_violation']:.3g}; the error "
              f"settles at {metrics['error_floor']:.3g} (a plant other than the design model has a mismatch floor)")
    if "dhat_rms_error" in metrics:
        p("  dhat rms error       " + ", ".join(f"{v:.4g}" for v in metrics["dhat_rms_error_second_half"])
          + " (second half of the run)")
    if "validity" in metrics:                      # a delayed observer with parameter identification
        _print_delayed(metrics, p)
    for key, path in (paths or {}).items():
        p(f"  {key:20s} {path}")


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
