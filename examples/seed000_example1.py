"""Seed 000 (Ichalal & Mammar, CDC 2019), Example 1, with the classical UIO.

The plant has an invariant zero at 0.99: no gain of the classical UIO can move it, so the
error decays like 0.99^k at best. This script designs the classical UIO with the fastest
certified decay, builds it and the plant as FMUs, co-simulates them (u_k = sin(k),
d_k = sin(2k) cos(3k), dt = 0.1 s) and plots x2 against its estimate and the error norm
against the certified bound.

    python examples/seed000_example1.py          # writes examples/out/seed000_example1/
    UIOFMU_EXAMPLES_OUT=/tmp/ex python examples/seed000_example1.py  # writes /tmp/ex/seed000_example1/
"""

import numpy as np

from _common import OUT, ROOT, design_and_build, main_guard


def main():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from uiofmu.cosim.master import cosimulate, write_outputs
    from uiofmu.cosim.steps import step_sequence

    out = OUT / "seed000_example1"
    problem, card, obs, plant = design_and_build(ROOT / "examples" / "seed000_example1.toml", out)
    zeros = ", ".join(f"{z[0]:.4g}" for z in card.data["invariant_zeros"])
    print(f"invariant zeros of (A, E, C): {zeros}; certified decay {card.data['decay_bound']:.6g} per step, "
          f"overshoot {card.data['overshoot_bound']:.4g}")
    result = cosimulate(plant, obs, step_sequence("fixed:0.1", 60.0))
    write_outputs(result, out, title="seed 000 Example 1: classical UIO")
    m = result.metrics
    print(f"co-simulation: {m['steps']} steps, error {m['initial_error_norm']:.3g} -> {m['final_error_norm']:.3g}, "
          f"1 % after {m['steps_to_1pct']} steps, bound respected: {m['bound_respected']}")

    k = np.arange(len(result.times))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    a.plot(k, result.x[:, 1], label="x2")
    a.plot(k, result.xhat[:, 1], "--", label="x2 estimate (classical UIO)")
    a.set_xlabel("k")
    a.set_ylabel("x2")
    a.set_title("Fig. 1 (classical part): x2 and its estimate")
    a.legend()
    e = np.linalg.norm(result.x - result.xhat, axis=1)
    b.semilogy(k, e, label="||e_k|| measured in co-simulation")
    b.semilogy(k, m["certified_overshoot"] * m["certified_decay"] ** k * e[0], "k--", label="certified bound")
    b.semilogy(k, e[0] * 0.99 ** k, ":", label="0.99^k (the invariant zero)")
    b.set_xlabel("k")
    b.set_ylabel("||e_k||")
    b.legend()
    b.set_title("error norm")
    fig.savefig(out / "figure1_classical.png", dpi=110)
    print(f"figures in {out}")


if __name__ == "__main__":
    main_guard(main)
