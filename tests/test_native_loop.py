"""The master's stepping in C (:mod:`uiofmu.cosim.native`) against its Python loop, with real C FMUs on fmpy:
the same histories bit for bit on every family's example, on aperiodic steps, with sensor noise and
quantisation, and the same error when an FMU refuses a call; the Python loop where an FMU is a pythonfmu one."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from tests.conftest import EXAMPLES
from uiofmu.cosim import native
from uiofmu.cosim.fmi import Fmu
from uiofmu.cosim.master import cosimulate, default_steps
from uiofmu.cosim.steps import step_sequence
from uiofmu.fmu.export import build_observer, build_plant
from uiofmu.problem import problem_from_data
from uiofmu.runtime.errors import FmuError

#: The session cards of each family's example (tests/conftest.py) and the time each run lasts.
FAMILIES = {"example1_card": 30.0,        # lti-uio
            "ltv_card": 30.0,             # ltv-auid
            "setup2_card": 25.0,          # switched, threshold rule: the plant's Integer mode feeds the observer
            "needs_theta_card": 20.0,     # deadbeat-functional, theta from the source to both FMUs
            "building_card": 180000.0}    # sampled-data, on the aperiodic steps of its intervals


def plant_of(card, folder, backend: str = "c"):
    """The plant FMU of a card's problem."""
    problem = problem_from_data(copy.deepcopy(card.data["problem"]), default_name=card.name)
    return build_plant(problem.plant, problem.name, folder / f"plant-{backend}.fmu", backend=backend)


@pytest.fixture(scope="module")
def pairs(request, observer_fmus, tmp_path_factory):
    """``pairs(name)``: ``(card, plant FMU, observer FMU)`` of a session card on the C backend."""
    made: dict = {}

    def get(name: str):
        if name not in made:
            card, observer = observer_fmus(name, "c")
            made[name] = card, plant_of(card, tmp_path_factory.mktemp(name)), observer
        return made[name]

    return get


def same_bits(a, b) -> bool:
    """Whether two arrays hold the same doubles bit for bit (NaN where NaN is, -0.0 where -0.0 is)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def assert_same_run(python, c) -> None:
    """Every history of the two results (the table's columns, the noise's arrays) and every metric equal."""
    assert list(python.columns()) == list(c.columns())
    for name, column in python.columns().items():
        assert same_bits(column, c.columns()[name]), name
    for name in ("times", "h", "x", "xhat", "y", "u", "d", "r", "dhat", "mode", "bound"):
        if getattr(python, name) is not None:
            assert same_bits(getattr(python, name), getattr(c, name)), name
    for part in ("noise", "functional", "delayed"):
        one, other = getattr(python, part), getattr(c, part)
        assert (one is None) == (other is None), part
        for key, value in (one or {}).items():
            if isinstance(value, np.ndarray):
                assert same_bits(value, other[key]), (part, key)
    assert json.dumps(python.metrics, sort_keys=True) == json.dumps(c.metrics, sort_keys=True)


def both_loops(plant, observer, steps, **options):
    """The run on the Python loop and on the C driver (which must have stepped it)."""
    python = cosimulate(plant, observer, steps, show_progress=False, native=False, **options)
    c = cosimulate(plant, observer, steps, show_progress=False, **options)
    assert c.timing["native"] is True, "the C driver did not step a pair of C FMUs"
    assert python.timing["native"] is False
    return python, c


def test_the_driver_is_built_and_cached():
    run = native.driver()
    assert run is not None
    assert [p.name for p in native.cache_folder().glob("native_loop-*.so")]


@pytest.mark.parametrize("name", FAMILIES)
def test_every_family_steps_the_same_in_c(pairs, name):
    card, plant, observer = pairs(name)
    steps = step_sequence(default_steps(card), FAMILIES[name], seed=4)
    python, c = both_loops(plant, observer, steps)
    assert c.timing["native"] is True and python.timing["native"] is False
    assert c.timing["fmi_calls_per_step"] == python.timing["fmi_calls_per_step"]
    assert_same_run(python, c)
    assert np.all(np.isfinite(c.x)) and len(c.times) == len(steps) + 1


def test_aperiodic_steps_are_aperiodic(pairs):
    card, plant, observer = pairs("building_card")
    steps = step_sequence("dropout:600:0.3:11", 172800.0, seed=11)
    assert len(set(steps.tolist())) > 3                       # the steps the C driver took vary
    python, c = both_loops(plant, observer, steps, xhat0=[19.0, 23.5])
    assert_same_run(python, c)


@pytest.mark.parametrize("name,noise,quantum", [("example1_card", "y=0.05,3", None),
                                                ("building_card", "y=0.02,9", 0.01),
                                                ("setup2_card", "y=0.01,2", None),
                                                ("needs_theta_card", "y=[0.01],5", None)])
def test_noise_and_its_twin_step_the_same_in_c(pairs, name, noise, quantum):
    card, plant, observer = pairs(name)
    steps = step_sequence(default_steps(card), FAMILIES[name], seed=8)
    python, c = both_loops(plant, observer, steps, noise=noise, quantization=quantum)
    assert python.noise is not None and np.any(python.noise["v"] != 0)
    assert_same_run(python, c)


def test_a_switched_plant_driven_by_its_integer_input(tmp_path):
    """The source's Integer mode goes to the plant and the observer as fmi2Integers."""
    import uiofmu
    from uiofmu.problem import load_problem, to_toml

    data = copy.deepcopy(load_problem(EXAMPLES / "seed002_three_modes.toml").data)
    data["plant"]["switching"] = {"rule": "input"}
    data["signals"]["mode"] = [[{"kind": "constant", "value": 1.0}, {"kind": "step", "time": 0.95, "value": 2.0}]]
    (tmp_path / "input.toml").write_text(to_toml(data))
    problem = uiofmu.load_problem(tmp_path / "input.toml")
    card = uiofmu.design(problem)
    observer = build_observer(card, tmp_path / "observer.fmu", backend="c")
    plant = build_plant(problem.plant, problem.name, tmp_path / "plant.fmu", backend="c")
    python, c = both_loops(plant, observer, step_sequence(default_steps(card), 5.0))
    assert set(c.mode[:-1]) == {1.0, 3.0}
    assert_same_run(python, c)


def errors_of(plant, observer, steps, **options) -> tuple:
    """The error each loop raises."""
    raised = []
    for loop in (False, True):
        with pytest.raises(FmuError) as info:
            cosimulate(plant, observer, steps, show_progress=False, native=loop, **options)
        raised.append(info.value)
    return tuple(raised)


@pytest.mark.parametrize("noise", [None, "y=0.01,1"])
def test_a_refused_step_stops_both_loops_with_one_message(pairs, noise):
    card, plant, observer = pairs("example1_card")
    steps = np.array([0.1] * 20 + [0.25] + [0.1] * 5)
    python, c = errors_of(plant, observer, steps, noise=noise)
    assert type(python) is type(c) and str(python) == str(c)
    assert "refused step 20 (t = 2 s, h = 0.25 s)" in str(c)


def test_a_refused_call_stops_the_driver_with_its_status_and_log(pairs):
    """A plant whose fmi2SetReal is refused (terminated): the driver raises what :meth:`Fmu.set` raises, with
    the FMU's log line of that call only (not the lines it wrote before)."""
    from uiofmu.cosim.fmi import FmuCallError

    card, plant_path, _ = pairs("example1_card")
    raised = []
    for loop in (False, True):
        with Fmu(plant_path, "plant") as plant:
            plant.initialize(0.0)
            plant.messages.append("a line of an earlier call")
            plant.logged.value = len(plant.messages)
            plant.slave.terminate()
            values = np.zeros((4, len(plant.refs("u"))))
            with pytest.raises(FmuCallError) as info:
                if loop:
                    program = native.Program(np.arange(4.0) * 0.1, np.full(3, 0.1))
                    program.values(plant, "fmi2SetReal", ["u"], values)
                    program.step(plant, "plant")
                    program.run(_Bar())
                else:
                    plant.set("u", values[0])
            raised.append(info.value)
    python, c = raised
    assert str(python) == str(c) and python.status == c.status == 3
    assert python.function == c.function == "fmi2SetReal"
    assert python.messages == c.messages and len(c.messages) == 1 and "fmi2Terminate" in c.messages[0]


class _Bar:
    def update(self, n):
        pass


def test_kept_instances_are_reset_and_stepped_in_c(pairs):
    card, plant_path, observer_path = pairs("building_card")
    steps = step_sequence("dropout:600:0.3:11", 86400.0, seed=2)
    with Fmu(plant_path, "plant") as plant, Fmu(observer_path, "observer") as obs:
        runs = [cosimulate(plant_path, observer_path, steps, show_progress=False, instances=(plant, obs), card=card,
                           native=loop) for loop in (True, False, True)]
    assert [r.timing["native"] for r in runs] == [True, False, True]
    assert_same_run(runs[1], runs[0])
    assert_same_run(runs[1], runs[2])


@pytest.mark.parametrize("observer_backend,plant_backend", [("python", "c"), ("c", "python")])
def test_a_pythonfmu_fmu_keeps_the_python_loop(pairs, observer_fmus, tmp_path, observer_backend, plant_backend):
    card, plant, observer = pairs("example1_card")
    if observer_backend == "python":
        observer = observer_fmus("example1_card", "python")[1]
    if plant_backend == "python":
        plant = plant_of(card, tmp_path, "python")
    steps = step_sequence("fixed:0.1", 5.0)
    with Fmu(plant, "plant") as p, Fmu(observer, "observer") as o:
        assert native.native_binary(p) is (plant_backend == "c")
        assert native.native_binary(o) is (observer_backend == "c")
        assert native.available(p, o) is False
    default = cosimulate(plant, observer, steps, show_progress=False)
    python = cosimulate(plant, observer, steps, show_progress=False, native=False)
    assert default.timing["native"] is False
    assert_same_run(python, default)


def test_the_delayed_family_keeps_the_python_loop(delayed_card, observer_fmus, tmp_path):
    """A delayed-uio observer or plant has no C kernel: their pythonfmu FMUs keep the Python loop."""
    card, observer = observer_fmus("delayed_card", "python")
    plant = plant_of(card, tmp_path, "python")
    steps = step_sequence(default_steps(card), 1.0)
    default = cosimulate(plant, observer, steps, show_progress=False)
    python = cosimulate(plant, observer, steps, show_progress=False, native=False)
    assert default.timing["native"] is False
    assert_same_run(python, default)


def test_a_campaign_worker_steps_its_runs_in_c(pairs, tmp_path):
    """The worker's runs (FMUs kept, reset before each) on the C driver: the same results as on the Python loop,
    with sensor noise on some rows (the twin's loop)."""
    from uiofmu.cosim.campaign.file import load_campaign
    from uiofmu.cosim.campaign.fmus import prepare
    from uiofmu.cosim.campaign.sampling import scenario
    from uiofmu.cosim.campaign.worker import run_scenario

    card, plant, observer = pairs("example1_card")
    spec = tmp_path / "campaign.toml"
    spec.write_text(f'[campaign]\nobserver = "{observer}"\nplant = "{plant}"\nruns = 4\nseed = 5\nt_end = 20.0\n'
                    '[axes]\nxhat0_error = {kind = "normal", std = 2.0}\n'
                    'd_scale = {kind = "uniform", low = 0.5, high = 1.5}\n'
                    'noise_y = [0.0, 0.05]\n')
    campaign = load_campaign(spec)
    setup = prepare(campaign, tmp_path / "out")
    noisy = 0
    for row in range(4):
        sc = scenario(campaign, setup, row)
        noisy += any(s > 0 for s in sc.get("noise_y", ()))
        c, python = run_scenario(setup, sc), run_scenario(setup, sc, native=False)
        assert c.timing["native"] is True and python.timing["native"] is False
        assert_same_run(python, c)
    assert 0 < noisy < 4


def test_the_driver_converts_and_measures_as_numpy_does():
    """Its conversions (Real to Integer refusing a non-integer, Integer to Real) and the measurement (noise added,
    rounded half to even to the quantum) on arrays alone, against numpy's arithmetic and the loop's checks."""
    from uiofmu.cosim.fmi import first_non_integer
    from uiofmu.cosim.twin import measured

    rng = np.random.default_rng(3)
    y = np.concatenate([[[0.5, -0.5], [1.5, 2.5], [0.15, -0.25]], rng.normal(size=(7, 2)) * 10])
    v = np.concatenate([np.zeros((3, 2)), rng.normal(size=(7, 2))])
    for quantum in (None, 1.0, 0.1, 0.003):
        program = native.Program(np.arange(10.0), np.ones(9))
        target = np.zeros_like(y)
        program.measure(y, v, quantum, target)
        program.run(_Bar())
        expected = np.array([measured(v, quantum)(k, y[k]) for k in range(10)])
        assert same_bits(target, expected), quantum
    reals = np.array([[1.0, -2.0], [2147483647.0, -2147483648.0], [3.0, 2.5], [4.0, 4.0]])
    integers, back = np.zeros((4, 2), dtype=np.intc), np.zeros((4, 2))
    program = native.Program(np.arange(4.0), np.ones(3))
    stops = []

    def refused(k, status, mark):
        stops.append((k, status, mark))
        raise ValueError("refused")

    program.convert(reals, 0, integers, 0, 2, refused)
    program.convert(integers, 0, back, 0, 2, refused)
    with pytest.raises(ValueError):
        program.run(_Bar())
    assert stops == [(2, -1, 1)] and first_non_integer(reals[2]) == 1
    assert integers[:2].tolist() == [[1, -2], [2147483647, -2147483648]] and same_bits(back[:2], reals[:2])
    assert integers[2:].tolist() == [[0, 0], [0, 0]]                # nothing written from the refused point on


def test_cosim_python_loop_writes_the_same_table(pairs, cli, tmp_path):
    _, plant, observer = pairs("example1_card")
    for name, extra in (("native", ()), ("python", ("--python-loop",))):
        res = cli("cosim", "--plant", plant, "--observer", observer, "--t-end", "10", "--no-report",
                  "--noise", "y=0.01,4", "--out", tmp_path / name, *extra)
        assert res.code == 0, res.err
    assert (tmp_path / "native" / "results.csv").read_bytes() == (tmp_path / "python" / "results.csv").read_bytes()
    assert (tmp_path / "native" / "metrics.json").read_text() == (tmp_path / "python" / "metrics.json").read_text()
