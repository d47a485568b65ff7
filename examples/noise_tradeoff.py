"""Noise against speed on a plant with three outputs and one unknown input.

``uiofmu tradeoff`` draws the certified noise gain of the default and the least-noise designs over the
certified decays; ``observer.noise_gain = 1.5`` (in ``noise_tradeoff.toml``) picks the fastest decay whose
certified ``gain_y`` is at most 1.5. Its observer then runs against its plant with sensor noise (``cosim
--noise``) next to the fastest design's, and the measured noise gains are printed against the certified ones.

    python examples/noise_tradeoff.py        # writes examples/out/noise_tradeoff/
"""

from dataclasses import replace

from _common import OUT, ROOT, main_guard


def main():
    import uiofmu
    from uiofmu.cosim.master import cosimulate, default_steps, step_sequence
    from uiofmu.fmu.export import build_observer, build_plant
    from uiofmu.families.lti_uio import noise_options
    from uiofmu.tradeoff import tradeoff, write

    out = OUT / "noise_tradeoff"
    problem = uiofmu.load_problem(ROOT / "examples" / "noise_tradeoff.toml")
    png, table = write(tradeoff(problem, points=8), out / "tradeoff.png")
    print(f"trade-off: {png} (table {table.name})")
    plant = build_plant(problem.plant, problem.name, out / "plant.fmu")
    fastest = replace(problem, options=noise_options(problem.options, "max", "default"))
    for label, this in (("fastest decay", fastest), ("noise_gain = 1.5", problem)):
        card = uiofmu.design(this)
        observer = build_observer(card, out / f"{label.split()[0]}_observer.fmu")
        steps = step_sequence(default_steps(card), 60.0, seed=3)
        m = cosimulate(plant, observer, steps, noise="y=0.01,5").metrics
        print(f"{label}: decay {card.data['decay_bound']:.4g}, certified gain_y {card.data['noise']['gain_y']:.3g}, "
              f"measured {m['noise_gain_measured']:.3g} (respected: {m['noise_gain_respected']}), rms error "
              f"over the second half {max(m['noise_rms_error']):.3g}")


if __name__ == "__main__":
    main_guard(main)
