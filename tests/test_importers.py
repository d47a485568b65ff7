"""Third-party importers from the package registries run our FMUs (issue 15, item 5).

ecospy (pip; its native library's libtbb.so.12 comes from the pip wheel tbb, loaded by ``import_ecospy``)
runs the plant + observer loop of every family, and the histories equal those of our own
master, :func:`uiofmu.cosim.master.cosimulate`, with the same inputs (the problem's
``[signals]``) at the observer's default step. fmpy.simulate_fmu with the FMU's default
experiment runs every FMU we build to its stop time.

The FMUs are made by the command line, as a user makes them: ``uiofmu design``, ``uiofmu build
--backend c`` and ``--backend python``, ``uiofmu plant`` (whatever backend it picks) and ``uiofmu
plant --backend c`` for the loop of two C FMUs (no Python in either FMU).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import EXAMPLES, ROOT, run_cli
from importers import default_step, ecospy_equals_master, run_fmpy_default

#: family -> problem; the observer's default step is dt or the first design interval.
PROBLEMS = {
    "lti-uio": EXAMPLES / "seed000_example1.toml",
    "ltv-auid": EXAMPLES / "seed000_example1_ltv.toml",
    "sampled-data": ROOT / "plants" / "two_room_building",
}
#: the other families' examples, for the refused-step test (every kind of FMU we build)
MORE_PROBLEMS = {
    "switched": EXAMPLES / "seed002_setup2.toml",
    "deadbeat-functional": EXAMPLES / "seed003_example.toml",
    "delayed-uio": EXAMPLES / "seed001_example.toml",
}
BACKENDS = ("c", "python")
#: communication steps of the ecospy run
STEPS = 50


def _cli(*argv) -> None:
    result = run_cli(*argv)
    assert result.code == 0, f"uiofmu {' '.join(map(str, argv))} exited {result.code}:\n{result.err}"


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """``{family: {"card": path, "plant": path, "c": path, "python": path}}``, made lazily."""
    root = tmp_path_factory.mktemp("importers")
    made: dict = {}

    def get(family: str, kind: str):
        problem = {**PROBLEMS, **MORE_PROBLEMS}[family]
        entry = made.setdefault(family, {})
        if kind not in entry:
            folder = root / family
            folder.mkdir(exist_ok=True)
            if kind == "card":
                _cli("design", problem, "-o", folder / "design.json")
                entry[kind] = folder / "design.json"
            elif kind == "plant":
                _cli("plant", problem, "-o", folder / "plant.fmu")
                entry[kind] = folder / "plant.fmu"
            elif kind.startswith("plant-"):
                _cli("plant", problem, "-o", folder / f"{kind}.fmu", "--backend", kind[len("plant-"):])
                entry[kind] = folder / f"{kind}.fmu"
            else:
                card = get(family, "card")
                _cli("build", card, "-o", folder / f"observer_{kind}.fmu", "--backend", kind)
                entry[kind] = folder / f"observer_{kind}.fmu"
        return entry[kind]

    return get


def generation_tool(fmu) -> str:
    """The FMU's ``generationTool`` (PythonFMU ... for pythonfmu FMUs)."""
    from fmpy import read_model_description

    return read_model_description(str(fmu)).generationTool or "?"


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("family", PROBLEMS)
def test_ecospy_loop_equals_our_master(fmus, family, backend):
    from uiofmu.cosim.master import default_inputs, observer_card

    plant, observer = fmus(family, "plant"), fmus(family, backend)
    h = default_step(observer)
    inputs = default_inputs(observer_card(observer))  # the problem's [signals]: u and d are not zero
    what = f"{family}: plant by {generation_tool(plant)}, observer by {generation_tool(observer)}"
    ecospy_equals_master(plant, observer, h, STEPS, inputs, what=what)


def is_standalone(fmu) -> bool:
    """A C FMU of uiofmu: no execution tool, its sources inside, no pythonfmu resources."""
    import zipfile

    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    with zipfile.ZipFile(fmu) as z:
        names = z.namelist()
    return (md.coSimulation.needsExecutionTool is False and (md.generationTool or "").startswith("uiofmu")
            and "sources/fmi2_plumbing.c" in names and not any(n.endswith(".py") for n in names))


@pytest.mark.parametrize("family", PROBLEMS)
def test_ecospy_runs_a_loop_of_two_c_fmus_equal_to_our_master(fmus, family):
    """Issue 15: a closed loop of two C FMUs (plant + observer) in a native engine, no Python in the FMUs."""
    from uiofmu.cosim.master import default_inputs, observer_card

    plant, observer = fmus(family, "plant-c"), fmus(family, "c")
    assert is_standalone(plant) and is_standalone(observer)
    h = default_step(observer)
    ecospy_equals_master(plant, observer, h, STEPS, default_inputs(observer_card(observer)), what=family)


#: every FMU we build: the observers of every family with both backends, and the plants
DEFAULT_RUNS = [pytest.param(family, kind, id=f"{family}-{kind}")
                for family in PROBLEMS for kind in (*BACKENDS, "plant", "plant-python")]


@pytest.mark.parametrize("family, kind", DEFAULT_RUNS)
def test_fmpy_default_experiment_runs(fmus, family, kind):
    from fmpy import read_model_description

    fmu = fmus(family, kind)
    experiment = read_model_description(str(fmu)).defaultExperiment
    assert experiment is not None and experiment.stepSize and experiment.stopTime, "no <DefaultExperiment>"
    step, stop = float(experiment.stepSize), float(experiment.stopTime)  # fmpy keeps the strings
    interval = step  # fmpy's communication step: stepSize, doubled while stopTime / interval > 1000
    while stop / interval > 1000:
        interval *= 2
    why = (f"{family} {kind} FMU ({generation_tool(fmu)}), stepSize = {step!r}, stopTime = {stop!r}: "
           f"fmpy steps at {interval!r}")
    try:
        result = run_fmpy_default(fmu, timeout=120.0)  # fmpy raises FMICallException when a C FMU answers fmi2Error
    except RuntimeError as exc:  # FmpyStalled, or a run that stopped early or is not finite
        pytest.fail(f"{why}; {exc}")
    # after a Discard answered with fmi2Terminated = true (a pythonfmu observer), fmpy stops
    # quietly and returns what it has: the run must reach the stop time
    assert len(result) >= 2 and result["time"][-1] == pytest.approx(stop, rel=1e-12), (
        f"{why}; it stopped at t = {float(result['time'][-1])!r}")
    for name in result.dtype.names:
        assert np.all(np.isfinite(result[name])), name



@pytest.mark.parametrize("family, kind", DEFAULT_RUNS + [
    pytest.param(family, kind, id=f"{family}-{kind}") for family in MORE_PROBLEMS for kind in (*BACKENDS, "plant")])
def test_fmpy_ends_at_once_on_a_step_the_fmu_refuses(fmus, family, kind):
    """``fmpy simulate --output-interval H`` with an H the FMU will never take: the FMU refuses the
    first step with fmi2Discard and one log line, answers fmi2Terminated = true, and fmpy ends the
    run there (it used to repeat the step for ever). An FMU that takes any step runs to the end."""
    import fmpy

    fmu = fmus(family, kind)
    h = 0.37 * default_step(fmu)  # off every period and between any two design intervals
    lines, calls = [], [0]

    def logger(component, instance, status, category, message):
        lines.append((status, category.decode(errors="replace")))

    def step_finished(t, recorder) -> bool:
        calls[0] += 1
        return calls[0] < 200  # a loop is stopped here, and fails below

    result = fmpy.simulate_fmu(str(fmu), stop_time=20 * h, output_interval=h, logger=logger,
                               step_finished=step_finished, timeout=60.0)
    discards = [line for line in lines if line[1] == "logStatusDiscard"]
    # nothing else to say: fmpy extracts only resources/ and binaries/, and a pythonfmu FMU no longer
    # warns on every run that it cannot read modelDescription.xml there
    assert not [line for line in lines if line[0] == 1], f"{family} {kind}: warnings {lines}"
    assert calls[0] < 200, f"{family} {kind}: fmpy repeated a step ({len(discards)} refusals logged)"
    takes_any_step = family == "delayed-uio" or (family == "sampled-data" and kind.startswith("plant"))  # continuous
    assert bool(discards) != takes_any_step, f"{family} {kind}: {len(discards)} refusals"
    if discards:
        assert len(discards) == 1, discards
        assert float(result["time"][-1]) == 0.0, "the run ends where the FMU refused the step"
    else:
        assert float(result["time"][-1]) == pytest.approx(20 * h, rel=1e-9)
