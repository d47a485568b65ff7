"""Running rows of a campaign in one process (a Dask worker, or the command's own for a replay and
the figure): the FMUs loaded once per process and reset before each run.

Dask sends :func:`run_batch` to its workers by its module path; every worker process imports this
module, whose cache (:func:`load`) keeps the FMUs of the campaign it serves."""

from __future__ import annotations

import atexit
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...runtime.errors import UserError
from ...threads import single_blas_thread
from .fmus import Setup
from ..noise import Noise
from .file import Campaign
from .rows import HEAD, axis_cells, axis_columns
from .sampling import scaled_inputs, scenario


@dataclass
class Loaded:
    """The FMUs of a campaign in one process: paths, the observer's card, inputs and initial estimate,
    and the two FMU instances, loaded once and reset before each run."""

    plant: Path
    observer: Path
    inputs: object
    xhat0: np.ndarray | None
    t_end: float
    card: object = None
    instances: tuple | None = None

    def fmus(self, twin: bool = False, twin_plant: bool = False) -> tuple:
        """The plant and observer instances of this process (loaded on first use), with ``twin`` the
        observer's noise-free twin (a second instance of its FMU, for a run with sensor noise) and with
        ``twin_plant`` also the plant's (for a run with process noise)."""
        from ..fmi import Fmu

        if self.instances is None:
            self.instances = (Fmu(self.plant, "plant"), Fmu(self.observer, "observer"))
        if (twin or twin_plant) and len(self.instances) < 3:
            self.instances = (*self.instances, Fmu(self.observer, "observer-noise-free"))
        if twin_plant and len(self.instances) < 4:
            self.instances = (*self.instances, Fmu(self.plant, "plant-noise-free"))
        return self.instances[:4 if twin_plant else 3 if twin else 2]


_LOADED: dict = {}
_FOLDERS: list = []


@atexit.register
def _clean() -> None:
    for loaded in _LOADED.values():
        for fmu in loaded.instances or ():
            fmu.close()
    for folder in _FOLDERS:
        shutil.rmtree(folder, ignore_errors=True)


def load(setup: Setup) -> Loaded:
    """The campaign's FMUs in this process, cached by their digest: written once to a local folder
    (unless the paths of the preparing machine are at hand), with the observer's card read once."""
    hit = _LOADED.get((setup.digest, setup.t_end))
    if hit is not None:
        return hit
    from ..master import default_inputs, observer_card

    if setup.plant_path is not None and setup.observer_path is not None:
        plant, observer = setup.plant_path, setup.observer_path
    else:
        folder = Path(tempfile.mkdtemp(prefix="uiofmu_campaign_"))
        _FOLDERS.append(folder)
        plant, observer = folder / "plant.fmu", folder / "observer.fmu"
        plant.write_bytes(setup.plant_bytes)
        observer.write_bytes(setup.observer_bytes)
    card = observer_card(observer)
    xhat0 = np.asarray(card.data["initial"]["xhat0"], dtype=float) if setup.has_xhat0 else None
    loaded = Loaded(plant, observer, default_inputs(card), xhat0, setup.t_end, card)
    _LOADED[(setup.digest, setup.t_end)] = loaded
    return loaded


def run_scenario(setup: Setup, sc: dict, native: bool = True):
    """Co-simulate one scenario (:func:`uiofmu.cosim.master.cosimulate`), stepped in C where both FMUs have
    native binaries (``native``, :mod:`uiofmu.cosim.native`; the same results as the Python loop).

    Returns
    -------
    uiofmu.cosim.result.CosimResult

    Raises
    ------
    FmuError
        When an FMU refuses a call.
    """
    from ..master import cosimulate
    from ..steps import step_sequence

    loaded = load(setup)
    steps = step_sequence(sc["steps"], loaded.t_end, seed=sc["steps_seed"])
    inputs = scaled_inputs(loaded.inputs, sc["d_scale"]) if "d_scale" in sc else loaded.inputs
    xhat0 = loaded.xhat0 + np.asarray(sc["xhat0_error"]) if "xhat0_error" in sc else None
    params = {k[6:]: v for k, v in sc.items() if k.startswith("plant.")}
    if "plant_mismatch" in sc:
        params.update(mismatch=[sc["plant_mismatch"]], mismatch_seed=[sc["mismatch_seed"]])
    noise = Noise("y", tuple(sc["noise_y"]), sc["noise_seed"]) if any(s > 0 for s in sc.get("noise_y", ())) else None
    if any(s > 0 for s in sc.get("noise_w", ())):
        noise = Noise("w", tuple(sc["noise_w"]), sc["noise_w_seed"])
    quantum = sc.get("quantization") or None
    instances = loaded.fmus(twin=bool(noise or quantum), twin_plant=noise is not None and noise.signal == "w")
    return cosimulate(loaded.plant, loaded.observer, steps, inputs, xhat0=xhat0, plant_parameters=params or None,
                      show_progress=False, instances=instances, card=loaded.card, noise=noise, quantization=quantum,
                      native=native)


def scalar_metrics(metrics: dict) -> dict:
    """The metrics of one run that fit a table cell: numbers, booleans, None; a list (per state or
    channel) becomes its Euclidean norm."""
    out = {}
    for key, value in metrics.items():
        key = "n_steps" if key == "steps" else key      # "steps" is the axis column
        if isinstance(value, bool) or value is None or isinstance(value, (int, float)):
            out[key] = value
        elif isinstance(value, list) and value and all(isinstance(v, (int, float)) for v in value):
            out[key] = float(np.linalg.norm(value))
    return out


@single_blas_thread
def run_row(setup: Setup, sc: dict) -> dict:
    """One row of the table: the scenario's status (``ok``, ``failed``: an FMU refused or an input was
    bad; ``crashed``: anything else), its reason and its scalar metrics."""
    t0 = time.perf_counter()
    try:
        result = run_scenario(setup, sc)
    except UserError as exc:
        return {"status": "failed", "reason": " ".join(str(exc).split())[:500], "wall_s": time.perf_counter() - t0}
    except Exception as exc:  # noqa: BLE001 - a run's bug must not stop the campaign: it is recorded
        return {"status": "crashed", "reason": f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:500],
                "wall_s": time.perf_counter() - t0}
    return {"status": "ok", "reason": "", "wall_s": time.perf_counter() - t0, **scalar_metrics(result.metrics)}


def batch_results(campaign: Campaign, setup: Setup, rows: range, outcome) -> list:
    """The results of a batch of rows as the client writes them, each row's scenario (:func:`scenario`)
    given to ``outcome`` in row order (:func:`run_row` in a worker; a crash for every row of a batch whose
    worker was lost).

    Returns
    -------
    list of tuple
        Per row ``(row, cells, plant_mismatch, result)``: the row's axis cells for the table
        (:func:`axis_cells`, under the table's columns found once for the batch), its plant's mismatch
        (None without the axis) and ``outcome(scenario)``.
    """
    columns = HEAD + axis_columns(campaign, setup)
    out = []
    for row in rows:
        sc = scenario(campaign, setup, row)
        out.append((row, axis_cells(sc, columns), sc.get("plant_mismatch"), outcome(sc)))
    return out


@single_blas_thread
def run_batch(setup: Setup, campaign: Campaign, rows: range) -> list:
    """A Dask task: the rows ``rows`` made into scenarios and run one after the other in this worker
    (:func:`batch_results` of :func:`run_row`)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return batch_results(campaign, setup, rows, lambda sc: run_row(setup, sc))


__all__ = ["Loaded", "batch_results", "load", "run_batch", "run_row", "run_scenario", "scalar_metrics"]
