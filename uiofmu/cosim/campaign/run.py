"""Running a campaign: every row on a Dask cluster, a bounded window of batches in flight, the
outputs written together (:func:`run_campaign`); one row re-run alone (:func:`replay`)."""

from __future__ import annotations

import json
import time

from ...runtime.errors import UserError
from ...runtime.files import check_output_dir, write_atomic
from ...threads import single_blas_thread
from .file import Campaign
from .fmus import Setup, prepare
from .plot import plot_campaign
from .rows import RowFile, cell, flat, read_table
from .sampling import batches, scenario
from .scheduler import probe_scheduler, scheduler_address, start_client
from .staging import Staging
from .tally import Tally, summary
from .worker import batch_results, run_batch, run_scenario, scalar_metrics

#: Batches in flight per worker: submitted, running, or finished and waiting for an earlier batch
#: to be written (the client holds at most this many batches per worker).
BATCHES_PER_WORKER = 8


def _batch_size(campaign: Campaign, workers: int) -> int:
    if campaign.batch:
        return campaign.batch
    return int(min(64, max(1, campaign.runs // (8 * max(1, workers)))))


class _Run:
    """One campaign on a Dask client: a bounded window of batches in flight, their rows written in
    row order to a :class:`RowFile` and counted in a :class:`Tally`, checkpoints and outputs in a
    :class:`Staging` folder."""

    def __init__(self, campaign: Campaign, setup: Setup, client, stage: Staging, workers: int,
                 checkpoint_s: float):
        self.campaign, self.setup, self.client, self.stage, self.workers = campaign, setup, client, stage, workers
        self.rows = RowFile(stage.path("rows.part"), campaign, setup)
        self.tally = Tally(mismatch=campaign.plant_mismatch is not None)
        self.inflight: dict = {}      # future key -> (batch index, future, scenarios)
        self.waiting: dict = {}       # batch index -> (scenarios, results), finished before an earlier batch
        self.next = 0                 # the next batch to write
        self.t0 = time.perf_counter()
        self.checkpoint_s, self.last_checkpoint = checkpoint_s, time.perf_counter()

    def drive(self, bar) -> None:
        """Submit the batches, at most :data:`BATCHES_PER_WORKER` per worker in flight, and take their
        rows as they finish."""
        from distributed import as_completed

        shared = self.client.scatter([self.setup, self.campaign], broadcast=True)
        source = enumerate(batches(self.campaign, _batch_size(self.campaign, self.workers)))
        window = BATCHES_PER_WORKER * max(1, self.workers)
        finished = as_completed()
        self._fill(source, window, shared, finished)
        for fut in finished:
            index, _, rows = self.inflight.pop(fut.key)
            self.waiting[index] = self._results(fut, rows)
            fut.release()
            bar.update(len(rows))
            self._write_ready()
            self._checkpoint()
            self._fill(source, window, shared, finished)

    def _fill(self, source, window: int, shared, finished) -> None:
        while len(self.inflight) + len(self.waiting) < window:
            item = next(source, None)
            if item is None:
                return
            index, rows = item
            fut = self.client.submit(run_batch, *shared, rows, pure=False)
            self.inflight[fut.key] = (index, fut, rows)
            finished.add(fut)

    def _results(self, fut, rows: range) -> list:
        try:
            return fut.result()
        except Exception as exc:  # noqa: BLE001 - a worker died (a crash inside an FMU) or was lost
            reason = f"worker lost: {type(exc).__name__}: {' '.join(str(exc).split())}"[:500]
            return batch_results(self.campaign, self.setup, rows, lambda sc: {"status": "crashed", "reason": reason})

    def _write_ready(self, everything: bool = False) -> None:
        """Write the finished batches that follow the rows written (``everything``: all of them, in order)."""
        for index in sorted(self.waiting) if everything else ():
            self._write(self.waiting.pop(index))
        while self.next in self.waiting:
            self._write(self.waiting.pop(self.next))
            self.next += 1

    def _write(self, batch) -> None:
        for row, cells, mismatch, result in batch:
            self.rows.add(cells, result)
            self.tally.add(row, result, mismatch)

    def _checkpoint(self) -> None:
        """Rewrite the table and summary in the staging folder, at most every ``checkpoint_s`` and at
        most a tenth of the time (the table is rewritten whole)."""
        if time.perf_counter() - self.last_checkpoint <= self.checkpoint_s:
            return
        t = time.perf_counter()
        self.write(cancelled=True)
        self.stage.checkpointed = True
        took = time.perf_counter() - t
        self.checkpoint_s = max(self.checkpoint_s, 10 * took)
        self.last_checkpoint = time.perf_counter()

    def cancel(self) -> None:
        """Cancel what is in flight and take the rows that finished."""
        self.client.cancel([fut for _, fut, _ in self.inflight.values()])
        self.inflight.clear()
        self._write_ready(everything=True)

    def write(self, cancelled: bool, **info) -> dict:
        """Write ``campaign.csv`` and ``summary.json`` of the rows so far into the staging folder."""
        self.rows.write_table(self.stage.path("campaign.csv"))
        data = summary(self.campaign, self.setup, self.tally, cancelled=cancelled, workers=self.workers,
                       elapsed=time.perf_counter() - self.t0, **info)
        write_atomic(self.stage.path("summary.json"), json.dumps(data, indent=2) + "\n", "campaign summary")
        return data

    def finish(self, cancelled: bool, **info) -> dict:
        """Write every output into the staging folder (the figure re-runs the worst row), then install them."""
        data = self.write(cancelled, **info)
        worst = data.get("worst_max_bound_ratio")
        result = run_scenario(self.setup, worst["scenario"]) if worst is not None else None
        plot_campaign(self.tally, result, worst, self.stage.path("campaign.png"),
                      f"{self.setup.name}: {self.campaign.runs} runs")
        self.rows.close()
        self.stage.install()
        return data


def run_campaign(campaign: Campaign, out, workers: int | None = None, scheduler: str | None = None,
                 show_progress: bool | None = None, say=None, checkpoint_s: float = 30.0) -> dict:
    """Run every row of a campaign on Dask and write ``campaign.csv``, ``summary.json``, ``campaign.png``.

    The outputs are replaced together (:class:`Staging`): a campaign that fails leaves the old ones
    as they were; while it runs, ``out/campaign.partial-*/`` holds a checkpoint of the table and
    summary (kept if the campaign fails after writing one).

    Parameters
    ----------
    campaign : Campaign
    out : str or Path
        Output folder.
    workers : int, optional
        Worker processes of the LocalCluster (default: ``os.cpu_count()``).
    scheduler : str, optional
        Address of an existing Dask scheduler instead (``tcp://host:8786``, :func:`scheduler_address`).
    show_progress : bool, optional
        Progress bar (default: when stderr is a terminal).
    say : callable, optional
        Where progress lines go.
    checkpoint_s : float
        The checkpoint is rewritten (atomically) at most this often while rows come in (and at most
        a tenth of the time).

    Returns
    -------
    dict
        The summary.

    Raises
    ------
    SchedulerError
        For a malformed scheduler address, or none that answers within :data:`SCHEDULER_TIMEOUT_S`.
    KeyboardInterrupt
        After writing the outputs of the rows that finished (``summary["cancelled"]`` is true).
    """
    from ...progress import progress

    out = check_output_dir(out, "--out folder")
    address = scheduler_address(scheduler) if scheduler is not None else None
    if address is not None:
        probe_scheduler(address)
    stage = Staging(out)
    client = cluster = None
    try:
        setup = prepare(campaign, out, say)
        t_start = time.perf_counter()
        client, cluster = start_client(workers, address)
        n_workers = len(client.scheduler_info(n_workers=-1)["workers"]) or (workers or 1)
        if say:
            where = f"scheduler {address}" if address else "a LocalCluster"
            say(f"  runs                 {campaign.runs} on {n_workers} worker(s) of {where}")
        run = _Run(campaign, setup, client, stage, n_workers, checkpoint_s)
        startup_s = run.t0 - t_start
        try:
            with progress(total=campaign.runs, desc="campaign", unit="run", enabled=show_progress) as bar:
                run.drive(bar)
        except KeyboardInterrupt:
            run.cancel()
            run.finish(cancelled=True, startup_s=startup_s)
            if say:
                say(f"  interrupted          {run.tally.finished} of {campaign.runs} runs kept in "
                    f"{out / 'campaign.csv'}")
            raise
        return run.finish(cancelled=False, startup_s=startup_s)
    finally:
        stage.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


@single_blas_thread
def replay(campaign: Campaign, out, row: int) -> dict:
    """Re-run one row alone and write its ``results.csv``, ``metrics.json``, ``report.png`` and
    ``scenario.json`` into ``out/row-ROW``.

    Returns
    -------
    dict
        ``scenario``, ``metrics`` (of the run, or None when it failed), ``status``, ``reason``,
        ``paths`` and ``matches`` (whether the row of ``out/campaign.csv``, when there is one, has the
        very same numbers; None without one).
    """
    from ..master import write_outputs
    from ..steps import short_spec

    out = check_output_dir(out, "--out folder")
    setup = prepare(campaign, out)
    sc = scenario(campaign, setup, row)
    folder = out / f"row-{row}"
    write_atomic(folder / "scenario.json", json.dumps(sc, indent=2) + "\n", "scenario")
    try:
        result = run_scenario(setup, sc)
    except UserError as exc:
        result, status, reason = None, "failed", " ".join(str(exc).split())[:500]
    else:
        status, reason = "ok", ""
    paths = {"scenario": folder / "scenario.json"}
    if result is not None:
        title = f"{setup.name}: campaign row {row}, steps {short_spec(sc['steps'])}"
        paths.update(write_outputs(result, folder, title=title))
    matches = None
    table = out / "campaign.csv"
    if table.is_file():
        recorded = {r["row"]: r for r in read_table(table)}.get(str(row))
        if recorded is not None:
            mine = {**flat(sc), "status": status, "reason": reason,
                    **(scalar_metrics(result.metrics) if result is not None else {})}
            matches = all(cell(mine.get(k)) == v for k, v in recorded.items() if k != "wall_s")
    return {"scenario": sc, "metrics": None if result is None else result.metrics, "status": status,
            "reason": reason, "paths": paths, "matches": matches}


__all__ = ["BATCHES_PER_WORKER", "replay", "run_campaign"]
