"""Seed 000 (Ichalal & Mammar, CDC 2019): the asymptotic-decoupling LTV observer against the
classical UIO, both as FMUs in co-simulation against the plant FMU.

Example 1 (Figs. 1 and 2): u_k = sin(k), d_k = sin(2k) cos(3k), dt = 0.1 s, alpha = 0.9,
eta = 0.01, mu = 90. The classical UIO cannot beat the invariant zero 0.99; the LTV observer
moves it during the transient.

Example 2 (Figs. 3 to 6): with the printed four-digit data one invariant zero is 1.00087 and
no observer exists (both checks are shown). With the data moved within its rounding so that
the zeros are the paper's 0.995 and 0.999, the LTV observer is designed with mu = "max"
(the paper finds mu = 15) and compared for alpha in {0.9, 0.98, 0.99, 0.993}.

    python examples/seed000_ltv_vs_classical.py    # writes examples/out/seed000_ltv/
    UIOFMU_EXAMPLES_OUT=/tmp/ex python examples/seed000_ltv_vs_classical.py  # writes /tmp/ex/seed000_ltv/
"""

import copy
import json

import numpy as np

from _common import OUT, ROOT, design_and_build, main_guard

EX = ROOT / "examples"


def run(plant, obs, steps, out, title):
    from uiofmu.cosim.master import cosimulate, write_outputs

    result = cosimulate(plant, obs, steps)
    write_outputs(result, out, title=title)
    return result


def eigen_trace(card, ks):
    """Eigenvalues of N_k over k, from the runtime's own schedule."""
    from uiofmu.runtime.observer import Runtime

    sched = Runtime(card).schedule
    return np.array([np.sort(np.abs(np.linalg.eigvals(sched.step_matrices(int(k), card.dt, card.dt)["N"])))
                     for k in ks])


def example1(plt, out):
    from uiofmu.cosim.steps import step_sequence

    _, ccard, cobs, plant = design_and_build(EX / "seed000_example1.toml", out / "fmus")
    _, lcard, lobs, _ = design_and_build(EX / "seed000_example1_ltv.toml", out / "fmus")
    steps = step_sequence("fixed:0.1", 60.0)
    rc = run(plant, cobs, steps, out / "classical", "seed 000 Example 1: classical UIO")
    rl = run(plant, lobs, steps, out / "ltv", "seed 000 Example 1: LTV observer")
    kc, kl = rc.metrics["steps_to_1pct"], rl.metrics["steps_to_1pct"]
    lam0 = max(abs(complex(*z)) for z in lcard.data["eigenvalues_N_k0"])
    summary = {"classical_steps_to_1pct": kc, "ltv_steps_to_1pct": kl, "speedup": kc / kl,
               "classical_final_error": rc.metrics["final_error_norm"],
               "ltv_final_error": rl.metrics["final_error_norm"],
               "invariant_zero": lcard.data["invariant_zeros"][0][0], "largest_eigenvalue_N_at_k0": lam0,
               "T1": lcard.data["matrices"]["T1"], "T2": lcard.data["matrices"]["T2"], "gamma": lcard.data["gamma"]}
    (out / "example1_comparison.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"Example 1: steps to 1 %: classical {kc}, LTV {kl} ({kc / kl:.1f}x faster); the zero 0.99 becomes "
          f"{lam0:.4f} at k = 0 (paper: 0.14)")
    k = np.arange(len(rc.times))
    fig, ax = plt.subplots(figsize=(8, 4), constrained_layout=True)
    ax.plot(k[:200], rc.x[:200, 1], "k", lw=1.5, label="x2")
    ax.plot(k[:200], rl.xhat[:200, 1], "--", label="LTV UIO")
    ax.plot(k[:200], rc.xhat[:200, 1], ":", label="classical UIO")
    ax.set_xlabel("k")
    ax.set_ylabel("x2")
    ax.set_title("Fig. 1: estimates of x2")
    ax.legend()
    fig.savefig(out / "fig1_x2_estimates.png", dpi=110)
    ks = np.arange(80)
    eig = eigen_trace(lcard, ks)
    fig, ax = plt.subplots(figsize=(8, 4), constrained_layout=True)
    ax.plot(ks, eig[:, -1], ".-", label="|λ_2(N_k)|")
    ax.plot(ks, eig[:, 0], ".-", label="|λ_1(N_k)|")
    ax.axhline(0.99, color="gray", ls=":", label="invariant zero 0.99")
    ax.set_xlabel("k")
    ax.set_ylabel("|λ(N_k)|")
    ax.set_title("Fig. 2: eigenvalues of N_k")
    ax.legend()
    fig.savefig(out / "fig2_eigenvalues.png", dpi=110)


def example2(plt, out):
    import uiofmu
    from uiofmu.problem import problem_from_data, to_toml
    from uiofmu.cosim.steps import step_sequence

    printed = uiofmu.load_problem(EX / "seed000_example2_printed.toml")
    for family in ("lti-uio", "ltv-auid"):
        data = copy.deepcopy(printed.data)
        data["observer"] = {"family": family} if family == "lti-uio" else data["observer"]
        report = uiofmu.check(problem_from_data(data))
        print(f"Example 2, printed data, {family}: " + ("exists" if report.exists else
              "no observer: " + "; ".join(c.message for c in report.failures)))
    path = EX / "seed000_example2_consistent.toml"
    consistent = uiofmu.load_problem(path)
    classical = copy.deepcopy(consistent.data)
    classical["name"] = "seed000-example2-classical"
    classical["observer"] = {"family": "lti-uio", "decay": "max"}
    tmp = out / "fmus" / "seed000_example2_classical.toml"
    tmp.parent.mkdir(parents=True, exist_ok=True)
    tmp.write_text(to_toml(classical))
    _, ccard, cobs, plant = design_and_build(tmp, out / "fmus")
    _, lcard, lobs, _ = design_and_build(path, out / "fmus")
    print(f"Example 2 (zeros 0.995, 0.999): mu max = {lcard.data['mu']:.4g} (paper: 15), tau_1 = "
          f"{lcard.data['tau1']:.4g}, classical decay {ccard.data['decay_bound']:.6g}")
    steps = step_sequence("fixed:0.1", 300.0)
    rc = run(plant, cobs, steps, out / "ex2_classical", "seed 000 Example 2: classical UIO")
    rl = run(plant, lobs, steps, out / "ex2_ltv", "seed 000 Example 2: LTV observer")
    k = np.arange(len(rc.times))
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True, constrained_layout=True)
    for i, ax in enumerate(axes):
        ax.plot(k, rc.x[:, i], "k", lw=1.2, label=f"x{i + 1}")
        ax.plot(k, rl.xhat[:, i], "--", label="LTV")
        ax.plot(k, rc.xhat[:, i], ":", label="classical")
        ax.set_ylabel(f"x{i + 1}")
        ax.legend(fontsize=8)
    axes[-1].set_xlabel("k")
    axes[0].set_title("Fig. 3: state estimates")
    fig.savefig(out / "fig3_states.png", dpi=110)
    fig, ax = plt.subplots(figsize=(8, 4), constrained_layout=True)
    ax.semilogy(k, np.linalg.norm(rl.x - rl.xhat, axis=1), label="LTV")
    ax.semilogy(k, np.linalg.norm(rc.x - rc.xhat, axis=1), label="classical")
    ax.set_xlabel("k")
    ax.set_ylabel("||e_k||")
    ax.set_title("Fig. 4: estimation error norm")
    ax.legend()
    fig.savefig(out / "fig4_errors.png", dpi=110)
    ks = np.arange(0, 1500, 10)
    eig = eigen_trace(lcard, ks)
    fig, ax = plt.subplots(figsize=(8, 4), constrained_layout=True)
    for j in range(eig.shape[1]):
        ax.plot(ks, eig[:, j], label=f"|λ_{j + 1}(N_k)|")
    ax.set_xlabel("k")
    ax.set_ylabel("|λ(N_k)|")
    ax.set_title("Fig. 5: eigenvalues of N_k")
    ax.legend()
    fig.savefig(out / "fig5_eigenvalues.png", dpi=110)
    fig, ax = plt.subplots(figsize=(8, 4), constrained_layout=True)
    ax.semilogy(k, np.linalg.norm(rc.x - rc.xhat, axis=1), "k:", label="classical")
    rows = {}
    for alpha in (0.9, 0.98, 0.99, 0.993):
        data = copy.deepcopy(consistent.data)
        data["name"] = f"seed000-example2-alpha{alpha}"
        data["observer"]["alpha"] = alpha
        p = out / "fmus" / f"alpha{alpha}.toml"
        p.write_text(to_toml(data))
        _, card, obs, _ = design_and_build(p, out / "fmus")
        r = run(plant, obs, steps, out / f"ex2_alpha{alpha}", f"Example 2, alpha = {alpha}")
        rows[alpha] = {"mu": card.data["mu"], "steps_to_1pct": r.metrics["steps_to_1pct"],
                       "final_error": r.metrics["final_error_norm"]}
        ax.semilogy(k, np.linalg.norm(r.x - r.xhat, axis=1), label=f"alpha = {alpha} (mu = {card.data['mu']:.3g})")
    ax.set_xlabel("k")
    ax.set_ylabel("||e_k||")
    ax.set_title("Fig. 6: effect of alpha")
    ax.legend(fontsize=8)
    fig.savefig(out / "fig6_alpha.png", dpi=110)
    (out / "example2_alpha.json").write_text(json.dumps(
        {"classical_steps_to_1pct": rc.metrics["steps_to_1pct"], "ltv": rows}, indent=2) + "\n")
    for alpha, row in rows.items():
        print(f"  alpha = {alpha}: mu max {row['mu']:.4g}, steps to 1 % {row['steps_to_1pct']}")
    print(f"  classical: steps to 1 % {rc.metrics['steps_to_1pct']}")


def main():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = OUT / "seed000_ltv"
    out.mkdir(parents=True, exist_ok=True)
    example1(plt, out)
    example2(plt, out)
    print(f"figures in {out}")


if __name__ == "__main__":
    main_guard(main)
