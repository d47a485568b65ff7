"""Seed 002 (Millerioux & Daafouz): the unknown-input observer for switched linear discrete systems,
from the problem file to the FMUs in co-simulation.

1. Setup 1 (one output): no observer exists; the check names mode 1's fixed eigenvalue -3.0427.
2. Setup 2 (two outputs): the one-step dead-beat design, its gains against the paper's.
3. Setup 2's FMUs (observer and switched plant) under the paper's switching rule with a bounded
   random unknown input (the paper's Figure 2), and under random switching.
4. A three-mode plant that is not dead-beat: the fastest certified decay is the joint spectral
   radius of the maps no gain moves (0.749928), and the measured error stays under the bound
   under random switching.

    python examples/seed002_switched.py    # writes examples/out/seed002_switched/
"""

import copy
import json

import numpy as np

from _common import ROOT, design_and_build, main_guard, output_folder, panels, savefig

EX = ROOT / "examples"
PAPER = {"K1": [[0, 0], [0.3166, -0.4893], [0.3166, -0.4893]], "K2": [[0, 0], [0.8295, 0.0236], [0.8295, 0.0236]],
         "Q": [[0.3333, 0.3333], [0.2060, -0.3176], [-0.4606, 0.0157]]}


def figure2(result, path, title):
    """The mode sequence and the error components (the paper's Figure 2), with the certified bound."""
    k = np.arange(len(result.times))
    fig, axes = panels(2, (8, 6))
    axes[0].step(k[:-1], result.mode[:-1], where="post")
    axes[0].set_yticks(sorted(set(result.mode[:-1].astype(int))))
    axes[0].set_ylabel("mode alpha_k")
    axes[0].set_title(title)
    err = np.abs(result.x - result.xhat)
    for i in range(err.shape[1]):
        axes[1].semilogy(k, np.maximum(err[:, i], 1e-18), label=f"|e{i + 1}|")
    if result.bound is not None:
        axes[1].semilogy(k, np.maximum(result.bound, 1e-18), "k--", lw=1, label="certified bound on ||e||")
    axes[1].set_xlabel("k")
    axes[1].set_ylabel("error")
    axes[1].legend(fontsize=8)
    savefig(fig, path)


def main():
    import uiofmu
    from uiofmu.cosim.master import cosimulate, write_outputs
    from uiofmu.cosim.steps import step_sequence
    from uiofmu.fmu.export import build_plant
    from uiofmu.problem import problem_from_data

    out = output_folder("seed002_switched")
    summary = {}

    setup1 = uiofmu.check(uiofmu.load_problem(EX / "seed002_setup1.toml"))
    fixed = {c.values["mode"]: [complex(*z).real for z in c.values["fixed_eigenvalues"]]
             for c in setup1.conditions if c.name.startswith("detectable")}
    summary["setup1"] = {"exists": setup1.exists, "fixed_eigenvalues": fixed}
    print(f"setup 1: observer exists: {setup1.exists}; fixed eigenvalues mode 1 {np.round(fixed[1], 4).tolist()}, "
          f"mode 2 {np.round(fixed[2], 4).tolist()} (paper: -3.0427, 0.6127 and -0.06837, -0.1313)")
    for c in setup1.failures:
        print(f"  {c.message}")

    problem, card, obs, plant = design_and_build(EX / "seed002_setup2.toml", out / "fmus")
    m = card.data["matrices"]
    gaps = {f"{name}{i + 1}": np.abs(np.array(m[name][i]) - PAPER[key]).max()
            for name in ("K", "Q") for i, key in enumerate(("K1", "K2") if name == "K" else ("Q", "Q"))}
    summary["setup2"] = {"design_method": card.data["design_method"], "decay_bound": card.data["decay_bound"],
                         "K": m["K"], "Q": m["Q"], "largest_gap_to_paper": {k: float(v) for k, v in gaps.items()}}
    print(f"setup 2: {card.data['design_method']} design, decay bound {card.data['decay_bound']:.3g}; largest "
          "difference to the paper's four digits: " + ", ".join(f"{k} {v:.1e}" for k, v in gaps.items()))

    steps = step_sequence("fixed:1.0", 200.0)
    rule = cosimulate(plant, obs, steps)
    write_outputs(rule, out / "setup2_threshold", title="seed 002 setup 2, threshold switching")
    figure2(rule, out / "fig2_threshold.png", "setup 2: the paper's rule (mode 2 when x1 >= 6)")
    data = copy.deepcopy(problem.data)
    data["plant"]["switching"] = {"rule": "random", "probabilities": [0.5, 0.5], "seed": 3}
    random_plant = build_plant(problem_from_data(data).plant, "seed002-setup2-random", out / "fmus" / "random.fmu")
    rand = cosimulate(random_plant, obs, step_sequence("fixed:1.0", 40.0))
    write_outputs(rand, out / "setup2_random", title="seed 002 setup 2, random switching")
    figure2(rand, out / "fig2_random.png", "setup 2: random switching (both modes unstable: 40 steps)")
    for name, r in (("threshold", rule), ("random", rand)):
        e = np.linalg.norm(r.x - r.xhat, axis=1)
        rel = float((e[1:] / np.maximum(1.0, np.linalg.norm(r.x[1:], axis=1))).max())
        summary[f"setup2_{name}"] = {"initial_error": float(e[0]), "largest_relative_error_after_one_step": rel,
                                     "switches": r.metrics["modes"]["switches"],
                                     "largest_state": float(np.abs(r.x).max())}
        print(f"  {name} switching: {r.metrics['modes']['switches']} switches, error {e[0]:.3g} at k = 0, then at "
              f"most {rel:.1e} of the state (largest |x| {np.abs(r.x).max():.3g})")

    _, card3, obs3, plant3 = design_and_build(EX / "seed002_three_modes.toml", out / "fmus")
    r3 = cosimulate(plant3, obs3, step_sequence("fixed:0.1", 20.0))
    write_outputs(r3, out / "three_modes", title="three modes, random switching")
    figure2(r3, out / "three_modes.png", f"three modes: certified decay {card3.data['decay_bound']:.6g} "
            "(joint spectral radius 0.749928)")
    summary["three_modes"] = {"decay_bound": card3.data["decay_bound"], "joint_spectral_radius": 0.749928,
                              "overshoot_bound": card3.data["overshoot_bound"],
                              "bound_respected": r3.metrics["bound_respected"],
                              "final_error": r3.metrics["final_error_norm"]}
    print(f"three modes: decay {card3.data['decay_bound']:.6g} (joint spectral radius 0.749928), bound respected: "
          f"{r3.metrics['bound_respected']}, final error {r3.metrics['final_error_norm']:.2e}")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"figures in {out}")


if __name__ == "__main__":
    main_guard(main)
