"""The FMUs of a campaign and what every run shares (:class:`Setup`): built from the campaign's
problem or read from the files it names, and checked against the campaign's axes."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from ...runtime.errors import FmuError, ProblemError, UserError
from ...runtime.files import parse_json, read_bytes, read_text, write_atomic
from .file import Campaign, not_a_folder


@dataclass
class Setup:
    """What the runs of a campaign share: the FMUs (as bytes, to ship to workers) and the sizes.

    Attributes
    ----------
    plant_bytes, observer_bytes : bytes
    digest : str
        Of both FMUs (the workers' cache key).
    t_end : float
    n : int
        Observer state size (of ``xhat0``).
    parameters : dict of str to int
        The plant FMU's parameter vectors and sizes.
    default_steps : str
    name : str
        The observer's problem name.
    has_xhat0 : bool
        Whether the observer has an initial estimate ``xhat0``.
    integers : tuple of str
        The plant parameters of the axes that are FMI Integers (their drawn values are ints).
    plant_path, observer_path : Path
        Where the FMUs are on the machine that prepared them.
    p : int
        The plant's number of outputs (of ``y``: the sensor noise axis has one std per output).
    r : int
        The plant's number of process-noise inputs (of ``w_noise``: the process noise axis has one std
        per column of ``W``).
    """

    plant_bytes: bytes
    observer_bytes: bytes
    digest: str
    t_end: float
    n: int
    parameters: dict
    default_steps: str
    name: str
    has_xhat0: bool
    integers: tuple = ()
    plant_path: Path = field(default=None, repr=False)
    observer_path: Path = field(default=None, repr=False)
    p: int = 0
    r: int = 0

    def __getstate__(self):
        state = dict(self.__dict__)
        state["plant_path"] = state["observer_path"] = None   # paths of the client machine only
        return state


def _digest(*blobs: bytes) -> str:
    h = hashlib.sha256()
    for b in blobs:
        h.update(hashlib.sha256(b).digest())
    return h.hexdigest()


def build_fmus(campaign: Campaign, folder, say=None) -> tuple[Path, Path]:
    """Design the observer of the campaign's problem and build both FMUs into ``folder``.

    The FMUs are reused when ``folder/source.json`` records the same problem file, backend and
    uiofmu version (a replay then runs on the very FMUs the campaign ran on).

    Returns
    -------
    (Path, Path)
        The plant and observer FMUs.
    """
    from ... import __version__
    from ...fmu.export import build_observer, build_plant
    from ...problem import load_problem
    from ...synthesis import design

    folder = Path(folder)
    path = campaign.problem / "problem.toml" if campaign.problem.is_dir() else campaign.problem
    source = {"problem": hashlib.sha256(read_bytes(path, "problem file", error=ProblemError)).hexdigest(),
              "backend": campaign.backend, "uiofmu": __version__}
    plant, observer, record = folder / "plant.fmu", folder / "observer.fmu", folder / "source.json"
    if record.is_file() and plant.is_file() and observer.is_file():
        try:
            if parse_json(read_text(record, "FMU record"), str(record)) == source:
                return plant, observer
        except UserError:
            pass
    problem = load_problem(campaign.problem)
    if say:
        say(f"  design               {problem.name} ({problem.family})")
    card = design(problem)
    card.write(folder / "design.json")
    build_observer(card, observer, campaign.backend)
    build_plant(problem.plant, problem.name, plant, step=problem.options.step, backend=campaign.backend,
                experiment_steps=problem.experiment_steps, labels=problem.labels)
    write_atomic(record, json.dumps(source, indent=2) + "\n", "FMU record")
    return plant, observer


def prepare(campaign: Campaign, out=None, say=None) -> Setup:
    """The FMUs (built into ``out/fmus`` for a problem) and the sizes the scenarios need.

    Raises
    ------
    ProblemError, FmuError
        For an axis the FMUs have no use for (a plant parameter the plant lacks, a vector of the
        wrong size), naming its key.
    """
    from ..fmi import read_description, vector_sizes
    from ..master import default_steps, default_t_end, observer_card

    if campaign.problem is not None:
        if out is None:
            raise ProblemError("campaign.problem: building the FMUs needs an output folder")
        plant, observer = build_fmus(campaign, Path(out) / "fmus", say)
    else:
        plant, observer = campaign.plant, campaign.observer
        for key, path in (("campaign.observer", observer), ("campaign.plant", plant)):
            not_a_folder(path, key, "an FMU file")
    card = observer_card(observer)
    variables = read_description(plant).modelVariables
    parameters = vector_sizes(variables, "parameter")
    initial = card.data.get("initial", {})
    has_xhat0 = "xhat0" in initial
    n = len(initial["xhat0"]) if has_xhat0 else 0
    if campaign.xhat0_error is not None:
        if not has_xhat0:
            raise ProblemError(f"axes.xhat0_error: the observer ({card.kernel} kernel) has no xhat0")
        campaign.xhat0_error.check_size(n)
    integers = _check_plant_axes(campaign, parameters, _vector_types(variables, "parameter"))
    if campaign.d_scale is not None:
        campaign.d_scale.check_size(1)
    p = vector_sizes(variables, "output").get("y", 0)
    if campaign.noise_y is not None:
        campaign.noise_y.check_size(p)
    if campaign.quantization is not None:
        campaign.quantization.check_size(1)
    r = vector_sizes(variables, "input").get("w_noise", 0)
    if campaign.noise_w is not None:
        if not r:
            raise ProblemError(f"axes.noise_w: the plant FMU {plant} takes no process noise (no input w_noise: its "
                               "problem declares no [plant] W)")
        if campaign.noise_y is not None or campaign.quantization is not None:
            raise ProblemError("axes.noise_w: process noise is measured alone (its twin loop is the noise-free plant "
                               "and observer); leave out axes.noise_y and axes.quantization")
        campaign.noise_w.check_size(r)
    if campaign.plant_mismatch is not None:
        campaign.plant_mismatch.check_size(1)
        if "mismatch" not in parameters:
            raise ProblemError(f"axes.plant_mismatch: the plant FMU {plant} takes no mismatch (no parameter "
                               "mismatch: only plants of matrices, linear or switched, perturb their A, B, E; "
                               "LPV, parametric and MuJoCo plants do not)")
        if any(name in ("mismatch", "mismatch_seed") for name, _ in campaign.plant_parameters):
            raise ProblemError("axes.plant_parameters: mismatch and mismatch_seed are set by axes.plant_mismatch")
    plant_bytes = read_bytes(plant, "plant FMU", error=FmuError)
    observer_bytes = read_bytes(observer, "observer FMU", error=FmuError)
    t_end = campaign.t_end if campaign.t_end is not None else default_t_end(card)
    check_steps_axis(campaign.steps, card, t_end)
    return Setup(plant_bytes, observer_bytes, _digest(plant_bytes, observer_bytes), t_end, n, parameters,
                 default_steps(card), card.name, has_xhat0, integers=integers, plant_path=Path(plant),
                 observer_path=Path(observer), p=p, r=r)


def _seconds(low: float, high: float) -> str:
    return f"a step of {low:g} s" if low == high else f"steps from {low:g} to {high:g} s"


def check_steps_axis(specs, card, t_end: float) -> None:
    """Refuse a step SPEC of the ``steps`` axis that can give a step the observer does not take.

    Parameters
    ----------
    specs : sequence of str
        The axis' SPECs.
    card : uiofmu.runtime.card.Card
        The observer's card (its schedule decides the steps it takes:
        :func:`uiofmu.runtime.schedules.takes_steps`).
    t_end : float
        The campaign's horizon (a step file's steps past it are not taken).

    Raises
    ------
    ProblemError
        Naming the axis value, a step it can give, the steps the observer takes and a SPEC it takes.
    """
    from ...runtime.schedules import make_schedule, takes_steps
    from ..master import default_steps
    from ..steps import short_spec, step_ranges

    schedule = make_schedule(card.schedule, card.matrices)
    for i, spec in enumerate(specs):
        bad = next(((lo, hi) for lo, hi in step_ranges(spec, t_end) if not takes_steps(schedule, lo, hi)), None)
        if bad is None:
            continue
        taken = ", ".join(f"{h:g}" for h in schedule.admissible_steps())
        what = "its design period" if len(schedule.admissible_steps()) == 1 else "one of its design intervals"
        raise ProblemError(f"axes.steps[{i}] = {short_spec(spec)!r}: {_seconds(*bad)}, and the observer takes only "
                           f"{what}, {taken} s (within {schedule.step_rtol:g} relative; schedule.step_policy = "
                           f"{schedule.policy!r}); e.g. {default_steps(card)}")


def _vector_types(variables, causality: str) -> dict:
    """The FMI type (``Real``, ``Integer``, ...) of each vector ``name[1..k]`` of one causality."""
    return {v.name[:v.name.index("[")]: v.type for v in variables
            if v.causality == causality and v.name.endswith("]") and "[" in v.name}


def _check_plant_axes(campaign: Campaign, sizes: dict, types: dict) -> tuple:
    """Check the plant-parameter axes against the plant FMU's parameters; the names of the Integer ones.

    Raises
    ------
    ProblemError
        For a parameter the plant lacks, a vector of the wrong size, a non-integer (or out of range)
        value of an Integer parameter, or a parameter neither Real nor Integer.
    """
    from ..fmi import FMI2_INTEGER

    integers = []
    for name, axis in campaign.plant_parameters:
        if name not in sizes:
            known = ", ".join(sizes) or "none"
            raise ProblemError(f"axes.plant_parameters.{name}: the plant FMU has no parameter {name} (it has {known})")
        axis.check_size(sizes[name])
        if types[name] == "Integer":
            axis.check_integers(f"the plant FMU's {name}, an Integer parameter,", *FMI2_INTEGER)
            integers.append(name)
        elif types[name] != "Real":
            raise ProblemError(f"axes.plant_parameters.{name}: the plant FMU's {name} is a {types[name]} parameter; "
                               "an axis sets Real and Integer ones")
    return tuple(integers)


__all__ = ["Setup", "build_fmus", "check_steps_axis", "prepare"]
