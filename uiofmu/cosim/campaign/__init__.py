"""Validation campaigns: many co-simulations of one observer against its plant, on Dask.

A campaign file (TOML, data only) names the FMUs (or a problem that gives them) and the axes a
run's scenario is drawn along: the step SPEC and its seed, an initial estimation error, a scale of
the unknown input, plant parameters. Every scenario is a function of the campaign's seed and the
row index only (:func:`scenario`), made by the worker that runs it (a batch is a range of rows:
:func:`batches`), so one row can be re-run alone and gives the same numbers bit for bit
(:func:`replay`). The runs go to a
``dask.distributed`` cluster (a ``LocalCluster`` of worker processes, or an existing scheduler,
checked with a deadline first: :func:`probe_scheduler`): each worker receives the FMUs once (their
bytes, so a worker on another machine needs no shared folder), keeps them with the observer's
default inputs in a per-process cache, and runs batches of rows through
:func:`uiofmu.cosim.master.cosimulate`. A bounded window of batches is in flight
(:data:`BATCHES_PER_WORKER`); finished rows go to a file in row order (:class:`RowFile`) and into
compact counters and arrays for the summary (:class:`Tally`), so the memory of the command's process
does not grow with the runs beyond 8 bytes per run and quantile figure. Every output is written
into a staging folder next to the outputs and moved into place only when all of them are complete
(:class:`Staging`). A run an FMU refuses is recorded with its reason; an interrupted campaign writes
the rows that finished.

Its parts, in the order a campaign goes through them:

- :mod:`~uiofmu.cosim.campaign.file`: the campaign file (its format, parsing and checks);
- :mod:`~uiofmu.cosim.campaign.fmus`: the FMUs and what every run shares (:class:`Setup`);
- :mod:`~uiofmu.cosim.campaign.sampling`: the scenarios of the rows, drawn along the axes;
- :mod:`~uiofmu.cosim.campaign.worker`: one batch of rows run in a worker process;
- :mod:`~uiofmu.cosim.campaign.scheduler`: the Dask cluster and the ``--scheduler`` address;
- :mod:`~uiofmu.cosim.campaign.rows`, :mod:`~uiofmu.cosim.campaign.tally`,
  :mod:`~uiofmu.cosim.campaign.staging`: the table, the summary and the staging folder of the outputs;
- :mod:`~uiofmu.cosim.campaign.run`: a whole campaign, and one row replayed;
- :mod:`~uiofmu.cosim.campaign.plot`: ``campaign.png``.

Every public name of these modules is importable from this package.
"""

from .file import AXES_KEYS, AXIS_LIMIT, CAMPAIGN_KEYS, KINDS, MAX_RUNS, MAX_SEED, Axis, Campaign, \
    campaign_from_data, load_campaign, parse_axis
from .fmus import Setup, build_fmus, check_steps_axis, prepare
from .plot import _hist, plot_campaign  # noqa: F401 - _hist: drawn and tested on its own
from .rows import HEAD, PREFERRED, RowFile, axis_columns, read_table
from .run import BATCHES_PER_WORKER, replay, run_campaign
from .sampling import batches, scaled_inputs, scenario, scenarios
from .scheduler import SCHEDULER_TIMEOUT_S, SchedulerError, probe_scheduler, scheduler_address
from .staging import OUTPUTS, Staging
from .tally import MAX_REASONS, QUANTILE_KEYS, QUANTILES, Tally, reason_kind, summary
from .worker import Loaded, batch_results, load, run_batch, run_row, run_scenario, scalar_metrics

__all__ = ["AXES_KEYS", "AXIS_LIMIT", "Axis", "BATCHES_PER_WORKER", "CAMPAIGN_KEYS", "Campaign", "HEAD", "KINDS",
           "Loaded", "MAX_REASONS", "MAX_RUNS", "MAX_SEED", "OUTPUTS", "PREFERRED", "QUANTILES", "QUANTILE_KEYS",
           "RowFile", "SCHEDULER_TIMEOUT_S", "SchedulerError", "Setup", "Staging", "Tally", "axis_columns",
           "batch_results", "batches", "build_fmus", "campaign_from_data", "check_steps_axis", "load", "load_campaign",
           "parse_axis", "plot_campaign", "prepare", "probe_scheduler", "read_table", "reason_kind", "replay",
           "run_batch", "run_campaign", "run_row", "run_scenario", "scaled_inputs", "scalar_metrics", "scenario",
           "scenarios", "scheduler_address", "summary"]
