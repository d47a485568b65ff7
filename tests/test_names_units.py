"""Names and units of a plant's states, inputs and outputs (``[plant] states``, ``state_units``, ...).

(a) A problem file's names and units are checked as data: counts against the dimensions (both numbers
in the message), names, units, duplicates; the CLI exits 2 with that one line.
(b) A card's copy is checked when the card is read (a forged card is refused).
(c) Both backends' observer and plant FMUs carry them in ``modelDescription.xml`` (fmpy reads
``description`` and ``unit``, and ``<UnitDefinitions>``), with the variable names unchanged; ``python -m
fmpy info`` lists them; no name reaches the generated C source.
(d) A co-simulation maps its columns to the labels in ``metrics.json``; the report's panels use them.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description

import uiofmu
from conftest import run_cli
from uiofmu.cosim.native_importers import FIXED_STEP_WARNING, run_compliance_checker
from uiofmu.fmu.c_backend import c_compiler
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import load_problem, problem_from_data
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import CardError, ProblemError

LABELS = {"states": ["position", "velocity"], "state_units": ["m", "m/s"], "inputs": ["force"],
          "input_units": ["N"], "unknown_inputs": ["friction"], "unknown_input_units": ["N"],
          "outputs": ["position_meas"], "output_units": ["m"]}


@pytest.fixture(scope="module")
def problem(example1_path):
    """Seed 000 Example 1 (lti-uio: fast) with every name and unit."""
    data = copy.deepcopy(load_problem(example1_path).data)
    data["plant"].update(LABELS)
    return problem_from_data(data)


@pytest.fixture(scope="module")
def card(problem):
    return uiofmu.design(problem)


@pytest.fixture(scope="module")
def fmus(problem, card, tmp_path_factory):
    """Observer and plant FMUs of the labelled problem, in every backend this machine builds."""
    out = tmp_path_factory.mktemp("labelled")
    backends = ["python"] + (["c"] if c_compiler() else [])
    built = {}
    for backend in backends:
        built[("observer", backend)] = build_observer(card, out / f"obs_{backend}.fmu", backend)
        built[("plant", backend)] = build_plant(problem.plant, problem.name, out / f"plant_{backend}.fmu",
                                                backend=backend, labels=problem.labels)
    return built


def test_the_problem_keeps_its_names_and_units(problem):
    assert problem.labels == LABELS


@pytest.mark.parametrize("key, value, message", [
    ("state_units", ["m", "m/s", "s"], "plant.state_units: 3 entries for 2 states (one per state)"),
    ("outputs", [], "plant.outputs: 0 entries for 1 output (one per output)"),
    ("unknown_inputs", ["a", "b"], "plant.unknown_inputs: 2 entries for 1 unknown input"),
    ("states", ["x", "x"], "plant.states: 'x' is given twice"),
    ("states", ["x", "a b"], "plant.states[1]: 'a b' is not a name"),
    ("states", ["x", '"/><x a="'], "plant.states[1]"),
    ("states", ["x", "1st"], "plant.states[1]: '1st' is not a name"),
    ("states", ["x", "y" * 65], "plant.states[1]: at most 64 characters, found 65"),
    ("states", ["x", "y\u202e"], "plant.states[1]: character U+202E at position 1 is not allowed"),
    ("state_units", ["m", "m/s\u00b2"], "plant.state_units[1]: 'm/s²' is not a unit"),
    ("state_units", ["m", "K<"], "plant.state_units[1]: 'K<' is not a unit"),
    ("input_units", [""], "plant.input_units[0]: expected a non-empty string"),
    ("inputs", "force", "plant.inputs: expected a list of strings, found str"),
    ("inputs", [3], "plant.inputs[0]: expected a string, found int"),
])
def test_bad_names_and_units_are_refused_naming_the_key(example1_path, key, value, message):
    data = copy.deepcopy(load_problem(example1_path).data)
    data["plant"][key] = value
    with pytest.raises(ProblemError) as info:
        problem_from_data(data)
    assert message in str(info.value)


def test_the_cli_exits_2_with_one_line(example1_path, tmp_path):
    text = example1_path.read_text().replace('x0 = [1.0, -1.0]', 'x0 = [1.0, -1.0]\nstate_units = ["m"]')
    path = tmp_path / "p.toml"
    path.write_text(text)
    result = run_cli("check", path)
    assert result.code == 2
    assert "plant.state_units: 1 entry for 2 states (one per state)" in result.err
    assert "Traceback" not in result.err


@pytest.mark.parametrize("key, value, message", [
    ("states", ["a", "b", "c"], "design card problem.plant.states: 3 entries for 2 states"),
    ("output_units", ["m&amp;"], "design card problem.plant.output_units[0]: 'm&amp;' is not a unit"),
    ("inputs", ["u", "u"], "design card problem.plant.inputs: 2 entries for 1 known input"),
])
def test_a_card_with_forged_names_is_refused_when_read(card, key, value, message):
    data = copy.deepcopy(card.data)
    data["problem"]["plant"][key] = value
    with pytest.raises(CardError) as info:
        card_from_data(data)
    assert message in str(info.value)


def test_the_card_keeps_them(card):
    assert card_from_data(json.loads(card.to_json())).labels == LABELS


#: What each FMU variable carries: (name, unit) of its element, by the FMI variable name.
OBSERVER_WANTS = {"xhat0[1]": ("position", "m"), "xhat0[2]": ("velocity", "m/s"), "y[1]": ("position_meas", "m"),
                  "u[1]": ("force", "N"), "xhat[1]": ("position", "m"), "xhat[2]": ("velocity", "m/s"),
                  "r[1]": ("position_meas", "m"), "dhat[1]": ("friction", "N")}
PLANT_WANTS = {"x0[1]": ("position", "m"), "x0[2]": ("velocity", "m/s"), "u[1]": ("force", "N"),
               "d[1]": ("friction", "N"), "y[1]": ("position_meas", "m"), "x[1]": ("position", "m"),
               "x[2]": ("velocity", "m/s"), "mismatch[1]": (None, None), "mismatch_seed[1]": (None, None)}


@pytest.mark.parametrize("role", ["observer", "plant"])
@pytest.mark.parametrize("backend", ["c", "python"])
def test_fmus_carry_names_and_units(fmus, role, backend):
    if (role, backend) not in fmus:
        pytest.skip("the C backend needs a C compiler")
    md = read_model_description(str(fmus[(role, backend)]))
    wants = OBSERVER_WANTS if role == "observer" else PLANT_WANTS
    variables = {v.name: v for v in md.modelVariables}
    assert set(variables) == set(wants), "the variable names are the FMI names, unchanged"
    for name, (label, unit) in wants.items():
        if label is not None:           # the plant's model-mismatch parameters name no quantity of the problem
            assert variables[name].description.startswith(f"{label}: "), (name, variables[name].description)
        assert variables[name].unit == unit, name
    assert sorted(u.name for u in md.unitDefinitions) == ["N", "m", "m/s"]


def test_no_name_reaches_the_c_source(fmus):
    if ("observer", "c") not in fmus:
        pytest.skip("the C backend needs a C compiler")
    for role in ("observer", "plant"):
        with zipfile.ZipFile(fmus[(role, "c")]) as z:
            sources = b"".join(z.read(n) for n in z.namelist() if n.startswith("sources/"))
        for word in ("position", "velocity", "friction", "force"):
            assert word.encode() not in sources, (role, word)


@pytest.mark.parametrize("role", ["observer", "plant"])
def test_the_compliance_checker_accepts_the_c_fmus(fmus, role, tmp_path):
    if ("observer", "c") not in fmus:
        pytest.skip("the C backend needs a C compiler")
    run = run_compliance_checker(fmus[(role, "c")], 0.1, 1.0, workdir=tmp_path)
    if not run.ran:
        pytest.skip(run.unavailable)
    assert not run.errors, run.log[-2000:]
    # its only warnings: an FMU of one step (honest canHandleVariableCommunicationStepSize="false") does not let
    # the checker shorten its last step to the stop time
    assert all(FIXED_STEP_WARNING in line for line in run.warnings), run.warnings


def test_fmpy_info_lists_them(fmus):
    out = subprocess.run([sys.executable, "-m", "fmpy", "info", str(fmus[("observer", "python")])],
                         capture_output=True, text=True, check=True).stdout
    line = next(row for row in out.splitlines() if row.strip().startswith("xhat[2]"))
    assert "m/s" in line and "velocity: state estimate" in line


def test_fmus_without_names_have_no_units(example1_card, tmp_path):
    card, _ = example1_card
    md = read_model_description(str(build_observer(card, tmp_path / "o.fmu", "python")))
    assert md.unitDefinitions == []
    assert all(v.unit is None for v in md.modelVariables)
    assert next(v for v in md.modelVariables if v.name == "xhat[1]").description == \
        "state estimate at the current communication point"


def test_cosim_labels_its_columns_and_report(fmus, tmp_path):
    from uiofmu.cosim.master import cosimulate, write_outputs
    from uiofmu.cosim.report import _plot_states, _unit_axis, pyplot

    backend = "c" if ("plant", "c") in fmus else "python"
    result = cosimulate(fmus[("plant", backend)], fmus[("observer", backend)], np.full(20, 0.1))
    paths = write_outputs(result, tmp_path / "run", report=False)
    labels = json.loads(paths["metrics"].read_text())["labels"]
    assert labels["x[2]"] == "velocity [m/s]"
    assert labels["xhat[1]"] == "position estimate [m]"
    assert labels["r[1]"] == "position_meas residual [m]"
    assert labels["dhat[1]"] == "friction estimate [N]"
    header = paths["results"].read_text().splitlines()[0].split(",")
    assert "xhat[1]" in header and "position" not in header
    plt, colors = pyplot()
    fig, (ax, ax_d) = plt.subplots(1, 2)
    _plot_states(ax, result.times, result, colors, "states")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "position [m]", "position estimate [m]", "velocity [m/s]", "velocity estimate [m/s]"]
    assert ax.get_ylabel() == "state (units in the legend)"   # two units: the legend says them
    _unit_axis(ax_d, result.labels, "d", 1, "unknown input", "d, dhat")
    assert ax_d.get_ylabel() == "friction [N]"
    plt.close(fig)


def test_report_drawn_again_keeps_the_names(fmus, tmp_path, cli):
    """`uiofmu report` of a labelled run: the same figure, names and units included (metrics.json's
    plant_labels); forged ones are refused naming the key."""
    from uiofmu.cosim.master import cosimulate, write_outputs

    backend = "c" if ("plant", "c") in fmus else "python"
    result = cosimulate(fmus[("plant", backend)], fmus[("observer", backend)], np.full(20, 0.1))
    run = tmp_path / "run"
    write_outputs(result, run, title="labelled")
    drawn = (run / "report.png").read_bytes()
    assert json.loads((run / "metrics.json").read_text())["plant_labels"]["states"] == ["position", "velocity"]
    (run / "report.png").unlink()
    assert cli("report", run).code == 0
    assert (run / "report.png").read_bytes() == drawn
    metrics = json.loads((run / "metrics.json").read_text())
    metrics["plant_labels"]["states"] = ["position"]
    (run / "metrics.json").write_text(json.dumps(metrics))
    res = cli("report", run)
    assert res.code == 2 and "plant_labels.states: 1 entry for 2 states" in res.err, res.err
