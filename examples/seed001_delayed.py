"""Seed 001 (Fouka, Nehaoua, Arioui, Mammar, L-CSS 2019): the delayed UIO with parameter identification,
from the problem file to the FMUs in co-simulation.

1. The check: rule (7) gives m = 1, the rank condition of C D_y stated on the signals, the premise
   family and its rank margins.
2. The design on the premise family (decay 5 1/s), and the card's honest bound.
3. Observer and plant FMUs in co-simulation with the premise's input, from the paper's initial
   estimate: state errors and thetahat against theta, at communication steps of 1 ms and 10 ms
   (how thetahat degrades with the step).
4. An input outside the premise family (sines at 1.3 and 3.1 Hz): sigma_min collapses, and the FMU
   flags those stretches invalid instead of reporting a thetahat there.

    python examples/seed001_delayed.py    # writes examples/out/seed001_delayed/
"""

import json

import numpy as np

from _common import ROOT, design_and_build, main_guard, output_folder, panels, savefig

EX = ROOT / "examples"


def figure(runs: dict, path, sigma_bound: float):
    """State error, thetahat error and the rank margin of each run, invalid stretches shaded."""
    fig, axes = panels(3, (9, 8))
    for name, r in runs.items():
        e = np.linalg.norm(r.x - r.xhat, axis=1)
        axes[0].semilogy(r.times, np.maximum(e, 1e-12), lw=1, label=name)
        extra = r.delayed
        eth = np.linalg.norm(extra["thetahat"] - extra["theta"], axis=1)
        axes[1].semilogy(r.times, np.where(extra["valid"] > 0.5, np.maximum(eth, 1e-12), np.nan), lw=1, label=name)
        axes[2].semilogy(r.times, np.maximum(extra["sigma_min"], 1e-12), lw=1, label=name)
    axes[2].axhline(sigma_bound, color="k", ls="--", lw=1, label="premise bound")
    axes[0].set_ylabel("||x - xhat||")
    axes[1].set_ylabel("||thetahat - theta|| (valid)")
    axes[2].set_ylabel("sigma_min(C D_y)")
    axes[2].set_xlabel("t [s]")
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    savefig(fig, path)


def main():
    import uiofmu
    from uiofmu.cosim.inputs import SignalInputs
    from uiofmu.cosim.master import cosimulate, write_outputs
    from uiofmu.cosim.steps import step_sequence
    from uiofmu.signals import parse_signals

    out = output_folder("seed001_delayed")
    path = EX / "seed001_example.toml"
    existence = uiofmu.check(uiofmu.load_problem(path))
    values = {c.name: c.values for c in existence.conditions}
    premise = values["rank C D_y on the premise family"]
    print(f"rule (7): m = {values['delays from rule (7)']['m_rule']}; {premise['symbolic']}")
    print(f"premise family: smallest sigma_min {premise['sigma_min']:.3g}, floor {premise['sigma_floor']:.3g}, "
          f"{100 * premise['left_out']:.1f} % of its points left out")

    problem, card, obs, plant = design_and_build(path, out / "fmus")
    print(f"design: decay {card.data['decay_rate']:g} 1/s, |K| = {card.data['gain_norm']:.4g}, substep "
          f"{card.schedule['max_substep']:.3g} s; {card.data['bound']}")

    runs, summary = {}, {"check": {k: values[k] for k in ("delays from rule (7)", "P_y D_y = 0")},
                         "decay_rate": card.data["decay_rate"], "runs": {}}
    outside = parse_signals([[{"kind": "sine", "amplitude": 20.0, "frequency_hz": 1.3},
                              {"kind": "sine", "amplitude": 10.0, "frequency_hz": 3.1}]], "signals.u", 1)
    for name, h, inputs in (("premise input, h = 1 ms", 1e-3, None), ("premise input, h = 10 ms", 1e-2, None),
                            ("outside the premise, h = 1 ms", 1e-3, SignalInputs(outside, ()))):
        r = cosimulate(plant, obs, step_sequence(f"fixed:{h}", 2.0), inputs)
        runs[name] = r
        folder = out / name.split(",")[0].replace(" ", "_") / f"h{h:g}"
        write_outputs(r, folder, title=f"seed 001: {name}")
        m = r.metrics
        late = r.times >= 1.5
        e = np.linalg.norm(r.x - r.xhat, axis=1)
        eth = np.linalg.norm(r.delayed["thetahat"] - r.delayed["theta"], axis=1)
        ok = late & (r.delayed["valid"] > 0.5)
        row = {"h": h, "validity": m["validity"]["fraction"], "invalid_stretches": m["validity"]["invalid_stretches"],
               "state_error_after_1.5s": float(np.median(e[late])),
               "theta_error_after_1.5s_when_valid": float(np.median(eth[ok])) if ok.any() else None,
               "final_thetahat": m["theta"]["final"]}
        summary["runs"][name] = row
        shown = "none valid" if row["theta_error_after_1.5s_when_valid"] is None else \
            f"{row['theta_error_after_1.5s_when_valid']:.2g}"
        print(f"{name}: valid {100 * row['validity']:.0f} % of the run ({row['invalid_stretches']} invalid stretches "
              f"after start-up); from 1.5 s median state error {row['state_error_after_1.5s']:.2g}, thetahat error "
              f"{shown} (theta = {problem.plant.theta.tolist()})")
    figure(runs, out / "errors_and_margin.png", card.schedule["sigma_bound"])
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"figures in {out}")


if __name__ == "__main__":
    main_guard(main)
