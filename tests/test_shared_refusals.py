"""The refusals the Python runtime and the C kernels share come from one catalogue
(uiofmu/runtime/refusals.py): (a) the generated C formats (``uiofmu_refusals.h``) write the text
Python writes; (b) a C FMU and the reference runtime refuse the same step or input with the same
words: a discrete plant given another step, an interval observer given a step that is none of its
intervals, an observer given an input that is not finite.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from cfmu import NEEDS_CC
from conftest import EXAMPLES
from uiofmu.cosim.fmi import Fmu, FmuCallError
from uiofmu.fmu.c_backend import refusals_header
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import load_problem
from uiofmu.runtime.observer import Runtime, RuntimeInputError
from uiofmu.runtime.plant_runtime import PlantRuntime
from uiofmu.runtime.refusals import REFUSALS, fields, refusal
from uiofmu.runtime.schedules import StepRejected

#: Values of each kind of field, as Python gets them and as the C code passes them to printf.
SAMPLES = {"num": (0.1, "0.1"), "int": (3, 3), "text": ("y", "y"), "g": (1e-09, 1e-09), "quoted": ("error", "error")}


@pytest.mark.parametrize("key", list(REFUSALS))
def test_the_c_format_writes_the_python_text(key):
    formats = dict(re.findall(r'#define UIOFMU_REFUSAL_(\w+) (".*")', refusals_header()))
    fmt = formats[key.upper()][1:-1].replace('\\"', '"').replace("\\\\", "\\")
    values = {name: SAMPLES[kind][0] for name, kind in fields(key)}
    args = tuple(SAMPLES[kind][1] for _, kind in fields(key))
    assert fmt % args == refusal(key, **values)                  # Python's % formats as C's printf does here


def test_every_field_has_a_known_kind():
    assert all(kind in SAMPLES for key in REFUSALS for _, kind in fields(key))


def _refusal_of(fmu_call) -> str:
    with pytest.raises(FmuCallError) as info:
        fmu_call()
    return " ".join(info.value.messages)


@NEEDS_CC
def test_a_discrete_plant_given_another_step(tmp_path):
    plant = load_problem(EXAMPLES / "seed000_example1.toml").plant
    h = 1.5 * plant.dt
    rt = PlantRuntime(plant.to_data())
    with pytest.raises(StepRejected) as info:
        rt.step(h)
    assert str(info.value) == refusal("plant_off_period", dt=plant.dt, h=h)
    with Fmu(build_plant(plant, "p", tmp_path / "p.fmu", backend="c"), "p") as fmu:
        fmu.initialize(0.0)
        assert f"t = 0.0: {info.value}" in _refusal_of(lambda: fmu.step(0.0, h))


@NEEDS_CC
def test_an_interval_observer_given_a_step_none_of_its_intervals(tmp_path, building_card):
    card = building_card[0]
    h = 1.37 * max(card.schedule["intervals"])
    rt = Runtime(card)
    with pytest.raises(StepRejected) as info:
        rt.step(h)
    assert str(info.value).startswith(f"step h = {h!r} s is not one of the design intervals {{")
    with Fmu(build_observer(card, tmp_path / "o.fmu", backend="c"), "o") as fmu:
        fmu.initialize(0.0)
        assert f"t = 0.0: {info.value}" in _refusal_of(lambda: fmu.step(0.0, h))


@NEEDS_CC
def test_an_observer_given_an_input_that_is_not_finite(tmp_path, example1_card):
    card = example1_card[0]
    rt = Runtime(card)
    rt.y[:] = [0.0] * card.dims["p"]
    rt.y[-1] = np.nan
    with pytest.raises(RuntimeInputError) as info:
        rt.step(card.schedule["dt"])
    with Fmu(build_observer(card, tmp_path / "o.fmu", backend="c"), "o") as fmu:
        fmu.initialize(0.0)
        fmu.set("y", rt.y)
        assert f"t = 0.0: {info.value}" in _refusal_of(lambda: fmu.step(0.0, card.schedule["dt"]))
