"""A MuJoCo quarter-car against a sampled-data UIO (aperiodic steps) and an LTV observer.

MJCF -> linearisation (cross-checked against MuJoCo) -> problem file -> observer FMUs ->
co-simulation with the MuJoCo plant FMU -> report. The same chain on the command line:

    uiofmu linearize plants/quarter_car -o out/qc.toml
    uiofmu design out/qc.toml -o out/qc.json
    uiofmu build out/qc.json -o out/sd.fmu
    uiofmu plant plants/quarter_car -o out/qc.fmu
    uiofmu cosim --plant out/qc.fmu --observer out/sd.fmu --steps choice:0.005,0.01,0.02,0.03,0.04,0.05 --out out/qc

    python examples/quarter_car.py               # writes examples/out/quarter_car/
    UIOFMU_EXAMPLES_OUT=/tmp/ex python examples/quarter_car.py  # writes /tmp/ex/quarter_car/
"""

import copy


from _common import OUT, ROOT, main_guard


def main():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import uiofmu
    from uiofmu.cosim.master import cosimulate, write_outputs
    from uiofmu.fmu.export import build_observer
    from uiofmu.mujoco_plant import build_mujoco_plant, linearize, load_spec, problem_document
    from uiofmu.problem import to_toml
    from uiofmu.problem import problem_from_data
    from uiofmu.cosim.steps import step_sequence

    out = OUT / "quarter_car"
    out.mkdir(parents=True, exist_ok=True)
    spec = load_spec(ROOT / "plants" / "quarter_car")
    lin = linearize(spec)
    print(f"linearisation from the MJCF parameters against MuJoCo finite differences: {lin.mismatch:.1e} relative")
    doc = problem_document(spec, lin)
    (out / "problem.toml").write_text(to_toml(doc, "linearised quarter-car (examples/quarter_car.py)"))
    sd_problem = uiofmu.load_problem(out / "problem.toml")
    ltv_doc = copy.deepcopy(doc)
    ltv_doc["name"] = "quarter-car-ltv"
    ltv_doc["observer"] = {"family": "ltv-auid", "dt": 0.01, "alpha": 0.95, "eta": 0.3, "mu": 1.0,
                           "xhat0": [0.0, 0.0, 0.0, 0.0]}
    ltv_problem = problem_from_data(ltv_doc)
    plant = build_mujoco_plant(spec, out / "quarter_car_mujoco.fmu")
    runs = {}
    for problem, steps_spec in ((sd_problem, "choice:0.005,0.01,0.02,0.03,0.04,0.05"), (ltv_problem, "fixed:0.01")):
        card = uiofmu.design(problem)
        card.write(out / f"{problem.name}.json")
        obs = build_observer(card, out / f"{problem.name}_observer.fmu")
        result = cosimulate(plant, obs, step_sequence(steps_spec, 5.0, seed=3))
        write_outputs(result, out / problem.name, title=f"MuJoCo quarter-car: {card.family} observer, {steps_spec}")
        runs[card.family] = result
        m = result.metrics
        print(f"{card.family:13s} {steps_spec:40s} error {m['initial_error_norm']:.3g} -> {m['final_error_norm']:.3g} "
              f"(floor {m['error_floor']:.2g}), dhat rms {m['dhat_rms_error_second_half'][0]:.3g} N, "
              f"certified bound respected: {m['bound_respected']}")
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True, constrained_layout=True)
    for ax, (family, r) in zip(axes, runs.items()):
        ax.step(r.times, r.d[:, 0], where="post", lw=1.2, label="road force d (N)")
        ax.plot(r.times[:-1], r.dhat[1:, 0], ".", ms=3, label="dhat")
        ax.set_title(f"{family}: unknown road force and its estimate")
        ax.set_ylabel("road force [N]")
        ax.legend(fontsize=8, loc="best")
    axes[-1].set_xlabel("time [s]")
    fig.savefig(out / "dhat_vs_d.png", dpi=110)
    plt.close(fig)
    print(f"figures in {out}")


if __name__ == "__main__":
    main_guard(main)
