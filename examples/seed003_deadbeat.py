"""Seed 003 (Fiacchini & Millerioux): the dead-beat functional observer of an LPV plant, from the problem
file to the FMUs in co-simulation.

1. The paper's example (``seed003_example.toml``): the existence theory step by step, every number read
   from ``uiofmu.check``: the inherent delay r = 2 of the rank condition (2); P(theta) = P_1 + theta_k P_2
   of (8), with the corrected entry -18 where the paper prints -14; the maximal robust invariant subspace
   span(e_3) of {P_i} in ker G (Algorithm 1); Phat_1, Phat_2 = 0, a nilpotent semigroup of class t = 2,
   so K = 1; the design's formula G x_k = 11 y_k + 2 y_k+1 (Proposition 4).
2. G = I is refused, with the reason (Phat_1 has the eigenvalue -1); G = [-4, 1, 0] is in the kernel of
   every P_i transposed (Proposition 6): K = 0 and G x_k = y_k+1.
3. The FMUs of the example: the LPV plant with theta = 3 x1 + 2 x2 from the state, which is the
   nonlinear system (17) exactly, against the observer, with a small random unknown input: gx equals
   3 x1 + 2 x2 (one step back) exactly from the first full window. (17) is unstable: 12 steps.
4. A plant whose formula needs theta (``seed003_needs_theta.toml``, theta an input of both FMUs) over
   400 steps: exact from the first full window to the end; the same formula with theta set to zero is
   wrong, so the observer really uses its theta input.

    python examples/seed003_deadbeat.py    # writes examples/out/seed003_deadbeat/
"""

import copy
import json

import numpy as np

from _common import ROOT, design_and_build, main_guard, output_folder, panels, savefig

EX = ROOT / "examples"
#: What the paper prints for P_theta's lower-left entry (its (3, 1) entry is -14 - theta_k there; -18 is right).
PAPER_ENTRY = -14.0


def relative_errors(result, window: int, true=None) -> np.ndarray:
    """``|gx - G x|`` relative to the data the formula reads: ``max(|G x|, max |y| over the window)``, NaN
    where ``gx`` is not valid (no floor at 1: the example's state starts at 1e-6). ``true``: the functional
    to compare with (default: the master's ``G x`` of the point ``delay`` steps back)."""
    f, y = result.functional, np.abs(result.y).max(axis=1)
    true = f["true"][:, 0] if true is None else true
    scale = np.array([np.nanmax([abs(true[k]), y[max(k - window + 1, 0):k + 1].max()]) for k in range(len(y))])
    err = np.abs(f["gx"][:, 0] - true) / np.maximum(scale, 1e-300)
    return np.where(f["valid"] > 0.5, err, np.nan)


def figure(result, err, path, title, linthresh=None):
    """The functional and its estimate (top; a symmetric log scale from ``linthresh`` when given), their
    relative difference (bottom, :func:`relative_errors`), the window-filling steps shaded."""
    f, m = result.functional, result.metrics
    k = np.arange(len(result.times))
    fig, axes = panels(2, (8, 6))
    for ax in axes:
        ax.axvspan(-0.5, m["valid_from"] - 0.5, color="0.9", label="window filling")
    axes[0].plot(k, f["true"][:, 0], "k-", lw=2, label=f"G x ({m['delay']} step(s) back)")
    axes[0].plot(k, np.where(f["valid"] > 0.5, f["gx"][:, 0], np.nan), ".--", color="C1", label="gx (observer FMU)")
    if linthresh:
        axes[0].set_yscale("symlog", linthresh=linthresh)
    axes[0].set_ylabel("functional")
    axes[0].set_title(title)
    axes[0].legend(fontsize=8)
    axes[1].semilogy(k, np.maximum(err, 1e-18), ".-" if len(k) <= 50 else ".", color="C3",
                     label="|gx - G x| / max(|G x|, max |y| on the window) (0 drawn at 1e-18)")
    axes[1].set_xlabel("k")
    axes[1].set_ylabel("relative error")
    axes[1].set_ylim(1e-18, 1e-12)
    axes[1].legend(fontsize=8)
    savefig(fig, path)


def main():
    import uiofmu
    from uiofmu.cosim.master import cosimulate, default_inputs, write_outputs
    from uiofmu.cosim.steps import step_sequence
    from uiofmu.families.deadbeat_functional import evaluate
    from uiofmu.fmu.export import build_observer
    from uiofmu.problem import problem_from_data

    out = output_folder("seed003_deadbeat")
    summary = {}

    # 1. the existence theory and the design of the paper's example
    problem = uiofmu.load_problem(EX / "seed003_example.toml")
    existence = uiofmu.check(problem)
    values = {c.name: c.values for c in existence.conditions}
    r = values["inherent delay"]["r"]
    P = np.array(values["P decomposition (8)"]["P"])
    invariant = values["robust invariant subspace in ker G"]
    basis, Phat = np.array(invariant["basis"]), np.array(invariant["Phat"])
    nil = values["nilpotent semigroup"]
    e3 = bool(basis.shape == (1, 3) and np.allclose(np.abs(basis[0]), [0, 0, 1], atol=1e-12))
    card = uiofmu.design(problem)
    F = card.matrices["F"][0, 0]
    lags = range(r - card.data["window"], r)                       # y_k-2 .. y_k+1 for the example
    summary["example"] = {
        "exists": existence.exists, "r": r, "P_1": P[0].tolist(), "P_2": P[1].tolist(),
        "P_1_lower_left": float(P[0][2, 0]), "paper_prints": PAPER_ENTRY,
        "monomials": values["P decomposition (8)"]["monomials"], "invariant_basis": basis.tolist(),
        "invariant_is_span_e3": e3, "Phat_1": Phat[0].tolist(), "Phat_2": Phat[1].tolist(),
        "Phat_2_is_zero": bool(not np.any(Phat[1])), "t": nil["t"], "K": nil["K"],
        "card": {k: card.data[k] for k in ("r", "K", "window", "delay", "formula")},
        "coefficients": {f"y_k{lag:+d}".replace("+0", ""): float(c) for lag, c in zip(lags, F)},
        "uses_theta": bool(card.matrices["Fexp"].any()),
    }
    print(f"example: r = {r} (rank condition (2)); P(theta) = P_1 + theta_k P_2 with")
    print(f"  P_1 = {P[0].tolist()}   (entry (3, 1): {P[0][2, 0]:g}; the paper prints {PAPER_ENTRY:g})")
    print(f"  P_2 = {P[1].tolist()}")
    print(f"  maximal robust invariant subspace in ker G: span{basis.round(12).tolist()} (span(e_3): {e3})")
    print(f"  Phat_1 = {Phat[0].tolist()}, Phat_2 = {Phat[1].tolist()}: nilpotent of class t = {nil['t']}, "
          f"K = {nil['K']}")
    print(f"  design: {card.data['formula']} (window of {card.data['window']} outputs, gx is G x of "
          f"{card.data['delay']} step(s) back); coefficients {summary['example']['coefficients']}")

    # 2. G = I refused, G = [-4, 1, 0] by Proposition 6
    data = copy.deepcopy(problem.data)
    data["observer"]["G"] = "identity"
    full = uiofmu.check(problem_from_data(data))
    reasons = [c.message for c in full.failures]
    summary["G_identity"] = {"exists": full.exists, "reasons": reasons}
    print(f"G = I: an observer exists: {full.exists}")
    for reason in reasons:
        print(f"  {reason}")
    data["observer"]["G"] = [[-4.0, 1.0, 0.0]]
    prop6 = uiofmu.check(problem_from_data(data))
    card6 = uiofmu.design(problem_from_data(data))
    summary["G_prop6"] = {"G": [[-4.0, 1.0, 0.0]], "exists": prop6.exists,
                          "proposition_6": next(c.message for c in prop6.conditions if c.name == "Proposition 6"),
                          "K": card6.data["K"], "formula": card6.data["formula"],
                          "coefficients": card6.matrices["F"][0, 0].tolist()}
    print(f"G = [-4, 1, 0]: {summary['G_prop6']['proposition_6']}; K = {card6.data['K']}, {card6.data['formula']}")

    # 3. the nonlinear plant (17) as an LPV plant FMU with theta from the state, against the observer FMU
    problem, card, obs, plant = design_and_build(EX / "seed003_example.toml", out / "fmus")
    obs_python = build_observer(card, out / "fmus" / "seed003-example_observer_python.fmu", backend="python")
    steps = step_sequence("fixed:1.0", 12.0)
    run = cosimulate(plant, obs, steps)
    again = cosimulate(plant, obs_python, steps)
    write_outputs(run, out / "example", title="seed 003: the nonlinear plant (17) and the observer of 3 x1 + 2 x2")
    x = run.x
    delay = card.data["delay"]
    direct = np.full(len(x), np.nan)
    direct[delay:] = 3 * x[:-delay, 0] + 2 * x[:-delay, 1]       # 3 x1 + 2 x2 of the point delay steps back
    err = relative_errors(run, card.data["window"], direct)
    figure(run, err, out / "example_functional.png", "(17) with a random unknown input: gx against 3 x1 + 2 x2",
           linthresh=1e-6)
    m = run.metrics
    summary["example_cosim"] = {
        "steps": m["steps"], "valid_from": m["valid_from"], "steps_to_exact": m["steps_to_exact"],
        "exact_from_first_full_window": m["exact_from_first_full_window"],
        "max_relative_error_vs_3x1_2x2": float(np.nanmax(err)), "largest_state": float(np.abs(x).max()),
        "initial_state": x[0].tolist(),
        "unknown_input_range": [float(run.d.min()), float(run.d.max())],
        "pythonfmu_observer_max_difference": float(np.abs(again.functional["gx"] - run.functional["gx"]).max()),
    }
    print(f"(17) in co-simulation, {m['steps']} steps: gx valid from step {m['valid_from']}, exact from step "
          f"{m['steps_to_exact']} (first full window: {m['exact_from_first_full_window']}); largest relative "
          f"error against 3 x1 + 2 x2: {np.nanmax(err):.1e} (largest |x| {np.abs(x).max():.3g}); the pythonfmu "
          f"observer differs by {summary['example_cosim']['pythonfmu_observer_max_difference']:.1e}")

    # 4. a plant whose formula needs theta, over a long run
    problem_t, card_t, obs_t, plant_t = design_and_build(EX / "seed003_needs_theta.toml", out / "fmus")
    h = card_t.schedule["dt"]
    run_t = cosimulate(plant_t, obs_t, step_sequence(f"fixed:{h!r}", 400 * h))
    write_outputs(run_t, out / "needs_theta", title="seed 003: a plant whose formula needs theta")
    err_t = relative_errors(run_t, card_t.data["window"])
    figure(run_t, err_t, out / "needs_theta_functional.png", f"theta an input: {card_t.data['formula']}")
    theta = np.array([default_inputs(card_t).values(t)["theta"] for t in run_t.times])
    L, ft = card_t.data["window"], run_t.functional
    F_t, exps = card_t.matrices["F"], card_t.matrices["Fexp"]
    no_theta = [evaluate(F_t, exps, run_t.y[k - L + 1:k + 1], np.zeros_like(theta[k - L + 1:k + 1]))[0]
                for k in range(L - 1, len(run_t.times))]
    wrong = np.abs(np.array(no_theta) - ft["true"][L - 1:, 0]) / np.maximum(1.0, np.abs(ft["true"][L - 1:, 0]))
    mt = run_t.metrics
    summary["needs_theta_cosim"] = {
        "formula": card_t.data["formula"], "r": card_t.data["r"], "K": card_t.data["K"],
        "uses_theta": bool(card_t.matrices["Fexp"].any()), "steps": mt["steps"], "valid_from": mt["valid_from"],
        "steps_to_exact": mt["steps_to_exact"], "exact_from_first_full_window": mt["exact_from_first_full_window"],
        "max_relative_error_when_valid": mt["max_relative_error_when_valid"],
        "max_relative_error_vs_window": float(np.nanmax(err_t)),
        "largest_state": float(np.abs(run_t.x).max()), "theta_range": [float(theta.min()), float(theta.max())],
        "median_relative_error_with_theta_zero": float(np.median(wrong)),
    }
    print(f"needs theta, {mt['steps']} steps: {card_t.data['formula']}; exact from step {mt['steps_to_exact']} "
          f"(first full window: {mt['exact_from_first_full_window']}), largest relative error "
          f"{mt['max_relative_error_when_valid']:.1e}; with theta set to zero the formula's median relative error "
          f"is {np.median(wrong):.2g}")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"figures in {out}")


if __name__ == "__main__":
    main_guard(main)
