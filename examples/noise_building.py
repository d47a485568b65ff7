"""The two-room building with noisy temperature sensors: what the noise does to the estimate.

The observer of ``plants/two_room_building`` (sampled-data, drop-outs of up to 11 samples) runs against
its plant with white sensor noise of three levels, each seeded, added between the plant and the observer
(``cosim --noise y=STD,SEED``). A noise-free twin of the observer runs in the same loop, so the noise's part
of the error is measured exactly: the measured l2 gain ``||e - e_twin|| / ||v||`` is printed against the
card's certified ``noise.gain_y`` where the card has one, with the error over the second half of each run.

    python examples/noise_building.py        # writes examples/out/noise_building/
"""

from _common import OUT, ROOT, design_and_build, main_guard


def main():
    from uiofmu.cosim.master import cosimulate, write_outputs
    from uiofmu.cosim.steps import step_sequence

    out = OUT / "noise_building"
    _, card, obs, plant = design_and_build(ROOT / "plants" / "two_room_building" / "problem.toml", out)
    certified = (card.data.get("noise") or {}).get("gain_y")
    print("certified noise gain: " + (f"{certified:.4g}" if certified is not None else "none in this card"))
    steps = step_sequence("dropout:600:0.3:11", 86400.0, seed=7)
    for std in (0.01, 0.05, 0.2):
        result = cosimulate(plant, obs, steps, noise=f"y={std},1")
        m = result.metrics
        rms = ", ".join(f"{v:.3g}" for v in m["noise_rms_error"])
        verdict = {True: "respected", False: "FALSE CERTIFICATE", None: "no certificate to compare"}
        print(f"noise std {std:g} K: measured gain {m['noise_gain_measured']:.4g} "
              f"({verdict[m['noise_gain_respected']]}), rms error {rms} K over the second half, "
              f"bound of the noise-free twin respected: {m['bound_respected']}")
        if std == 0.05:
            write_outputs(result, out, title="two-room building with sensor noise of std 0.05 K")


if __name__ == "__main__":
    main_guard(main)
