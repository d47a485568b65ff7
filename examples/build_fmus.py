"""``make fmus``: build the example observer and plant FMUs into a folder (default fmus/)."""

import argparse
from pathlib import Path

from _common import ROOT, design_and_build, main_guard

PROBLEMS = [ROOT / "examples" / "seed000_example1.toml", ROOT / "examples" / "seed000_example1_ltv.toml",
            ROOT / "plants" / "two_room_building" / "problem.toml", ROOT / "plants" / "quarter_car" / "problem.toml"]


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=str(ROOT / "fmus"))
    out = Path(parser.parse_args().out)
    for path in PROBLEMS:
        problem, card, obs, plant = design_and_build(path, out)
        print(f"{problem.name}: {obs.name}, {plant.name}")
    from uiofmu.mujoco_plant import build_mujoco_plant, load_spec

    mujoco = build_mujoco_plant(load_spec(ROOT / "plants" / "quarter_car"), out / "quarter-car_mujoco_plant.fmu")
    print(f"quarter-car: {mujoco.name}")


if __name__ == "__main__":
    main_guard(main)
