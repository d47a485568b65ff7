"""Two native FMI importers run on one FMU as separate programs: the FMU Compliance Checker and fmusim.

:func:`run_compliance_checker` runs ``fmuCheck.linux64 -h STEP -s STOP -n 0 -o out.csv -e log -t tmpdir FMU``
(modelica-tools/FMUComplianceChecker: it validates ``modelDescription.xml``, then simulates the FMU);
:func:`run_fmusim` runs ``fmusim --interface-type cs --output-interval STEP --stop-time STOP
--output-file out.csv FMU`` (the simulator of modelica/Reference-FMUs). Neither is on a package
registry: they are looked for in ``../shared/importers/`` next to the repository, or where
``$UIOFMU_FMUCHECK`` and ``$UIOFMU_FMUSIM`` say (:func:`importer_path`).

Both run in an environment with ``PATH`` only (no ``PYTHONPATH``, ``PYTHONHOME``, ``VIRTUAL_ENV``,
``LD_LIBRARY_PATH``): an FMU that passes needs no Python in the host process. Each returns an
:class:`ImporterRun`: the errors and warnings the program and the FMU reported, the time of the last
output row, or why the program could not run (absent, not executable, a shared library missing).
Neither program's exit code says everything: fmusim exits 0 after an FMU refused a step with
fmi2Discard, and the checker counts the FMU's own log lines apart from its own errors, so both logs are
read line by line. ``make fmus`` (:mod:`uiofmu.catalogue`) and the tests use both functions.
"""

from __future__ import annotations

import csv
import math
import os
import re
import subprocess
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

from ..runtime.tolerances import STEP_RTOL

#: The folder of the prebuilt importers, next to the repository (``../shared/importers/``).
IMPORTERS = Path(__file__).resolve().parents[3] / "shared" / "importers"
#: The Compliance Checker: its file in :data:`IMPORTERS` and the variable that overrides it.
FMUCHECK = ("fmuCheck.linux64", "UIOFMU_FMUCHECK")
#: fmusim: its file in :data:`IMPORTERS` and the variable that overrides it.
FMUSIM = ("fmusim", "UIOFMU_FMUSIM")
#: The checker's one warning on an FMU of one step (``canHandleVariableCommunicationStepSize="false"``):
#: it then does not shorten its last step to the stop time. The flag being honest, not a fault.
FIXED_STEP_WARNING = "FMU does not support variable communication stepsize"
#: What the dynamic loader prints when a program's shared library is missing.
_LOADER = "error while loading shared libraries"
#: FMU statuses that make a run fail (a refused step included), and those that are warnings.
_ERRORS = ("Discard", "Error", "Fatal")
_WARNINGS = ("Warning",)
_FMU_STATUS = re.compile(r"\[FMU status:(\w+)\]")
_FMUSIM_STATUS = re.compile(r"^\[(\w+)\]")


@dataclass(frozen=True)
class ImporterRun:
    """What one run of a native importer on one FMU found.

    Attributes
    ----------
    tool : str
        The program's file name (``fmuCheck.linux64``, ``fmusim``).
    fmu : Path
    step, stop : float
        The communication (output) step and the stop time asked for.
    unavailable : str
        Why the program could not run (not found, not executable, a library missing); empty when it ran.
    errors : tuple of str
        The lines that make the run fail: the program's own errors and the FMU's fmi2Discard,
        fmi2Error and fmi2Fatal lines, a non-zero exit code, an unreadable or non-finite output.
    warnings : tuple of str
        The program's and the FMU's warning lines.
    last_time : float or None
        The time of the last row of the output CSV (None when there is none).
    rows : tuple of list of str
        The output CSV without its header, one list of cells per row (time first).
    log : str
        Everything the program wrote (the checker's log file, fmusim's stdout and stderr).
    """

    tool: str
    fmu: Path
    step: float
    stop: float
    unavailable: str = ""
    errors: tuple = ()
    warnings: tuple = ()
    last_time: float | None = None
    rows: tuple = ()
    log: str = ""

    @property
    def ran(self) -> bool:
        """The program ran (whatever it found)."""
        return not self.unavailable

    @property
    def times(self) -> tuple:
        """The time of every output row."""
        return tuple(float(row[0]) for row in self.rows)

    @property
    def stop_time(self) -> float | None:
        """The time of the output row at the stop time, within the rounding of summing the steps (None
        when there is none).

        Adding the step K = stop / step times rounds each sum by at most half an ulp of the stop time,
        so the tolerance is K ulps of the stop time (at least one).
        """
        tolerance = max(1, round(self.stop / self.step)) * math.ulp(self.stop)
        return next((t for t in reversed(self.times) if abs(t - self.stop) <= tolerance), None)

    @property
    def past_stop(self) -> bool:
        """The last row is one step after the row at the stop time.

        The checker does not shorten the last step of an FMU of one step (:data:`FIXED_STEP_WARNING`),
        and it steps again while its clock, a sum of steps, is below the stop time, by rounding too.
        """
        at = self.stop_time
        return at is not None and self.last_time > at

    @property
    def reached_stop(self) -> bool:
        """A row is at the stop time (:attr:`stop_time`), and the last row is that one or one step after it
        (:attr:`past_stop`)."""
        at = self.stop_time
        return at is not None and self.last_time - at <= self.step * (1 + STEP_RTOL)

    @property
    def ok(self) -> bool:
        """It ran, with no error, to the stop time."""
        return self.ran and not self.errors and self.reached_stop

    def problem(self) -> str:
        """Why the run is not :attr:`ok`, in one line (empty when it is)."""
        if not self.ran:
            return f"not run: {self.unavailable}"
        if self.errors:
            return self.errors[0]
        if self.last_time is None:
            return "no output row"
        if not self.reached_stop:
            return f"its last output row is at t = {self.last_time!r}, not at the stop time {self.stop!r}"
        return ""


def importer_path(tool: tuple) -> Path:
    """Where an importer is looked for: its environment variable, else :data:`IMPORTERS`.

    Parameters
    ----------
    tool : tuple of str
        :data:`FMUCHECK` or :data:`FMUSIM`.

    Returns
    -------
    Path
    """
    name, variable = tool
    return Path(os.environ.get(variable) or IMPORTERS / name)


def bare_environment() -> dict:
    """The environment the importers run in: ``PATH`` only, so no Python variable reaches them."""
    return {"PATH": os.environ.get("PATH", "")}


def importer_missing(tool: tuple) -> str:
    """Why an importer cannot run as far as its file tells (a library it lacks shows only when it runs).

    Parameters
    ----------
    tool : tuple of str
        :data:`FMUCHECK` or :data:`FMUSIM`.

    Returns
    -------
    str
        Empty when the file is there and executable.
    """
    path = importer_path(tool)
    if not path.is_file():
        return f"{path} is not there (set ${tool[1]}, or see ../shared/importers/README.md)"
    if not os.access(path, os.X_OK):
        return f"{path} is not executable"
    return ""


def importer_unavailable(tool: tuple, timeout: float = 30.0) -> str:
    """Why an importer cannot run: :func:`importer_missing`'s reasons, or a shared library the system's loader
    does not find (the program is started once, with no arguments, to see).

    Parameters
    ----------
    tool : tuple of str
        :data:`FMUCHECK` or :data:`FMUSIM`.
    timeout : float
        Seconds the program may take to print its usage.

    Returns
    -------
    str
        Empty when it starts.
    """
    if missing := importer_missing(tool):
        return missing
    _, why, _ = _launch(tool, importer_path(tool), [], timeout)
    return why


def _folder(path) -> Path:
    """``path``, made where it is not there yet."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    return path


def _launch(tool: tuple, path: Path, args: list, timeout: float) -> tuple:
    """Run the program: ``(completed process or None, why it could not run or '', error or '')``."""
    try:
        proc = subprocess.run([str(path), *args], capture_output=True, text=True, errors="replace",
                              env=bare_environment(), timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, "", f"{tool[0]} did not finish within {timeout:g} s"
    except OSError as exc:
        return None, f"{path} cannot start: {exc}", ""
    text = proc.stdout + proc.stderr
    if proc.returncode == 127 and _LOADER in text:
        lines = [line for line in text.splitlines() if _LOADER in line]
        return None, f"{path} cannot start: {lines[0].strip()}", ""
    return proc, "", ""


def _exit_code(errors: list, who: str, code: int) -> None:
    """A non-zero exit code as the first error, with the first error line the program gave."""
    if code != 0:
        errors[:1] = [f"{who} exited with {code}" + (f": {errors[0]}" if errors else "")]


def _read_output(path: Path) -> tuple:
    """``(rows, last time, errors)`` of an importer's output CSV (time first, one header line)."""
    if not path.is_file():
        return (), None, ["no output file was written"]
    with open(path, newline="", encoding="utf-8", errors="replace") as f:
        table = [row for row in csv.reader(f) if row]
    header, rows = (table[0], table[1:]) if table else ([], [])
    errors = []
    for row in rows:
        for name, value in zip(header, row):
            try:
                number = float(value)
            except ValueError:
                continue                                   # a Boolean or String output
            if not math.isfinite(number):
                errors.append(f"the output {name} is {value} at t = {row[0]}")
                break
        if errors:
            break
    for row in rows:
        try:
            float(row[0])
        except ValueError:
            return (), None, errors + [f"an output row's time {row[0]!r} is not a number"]
    return tuple(rows), float(rows[-1][0]) if rows else None, errors


def _checker_lines(log: str) -> tuple:
    """The checker's errors and warnings: its own ``[ERROR]``/``[FATAL]``/``[WARNING]`` lines and the FMU's
    lines by their status."""
    errors, warnings = [], []
    for line in log.splitlines():
        line = line.strip()
        status = _FMU_STATUS.search(line)
        if line.startswith(("[ERROR]", "[FATAL]")) or (status and status.group(1) in _ERRORS):
            errors.append(line)
        elif line.startswith("[WARNING]") or (status and status.group(1) in _WARNINGS):
            warnings.append(line)
    counted = re.search(r"Checker reported:\s*\n\s*\d+ Warning\(s\)\s*\n\s*(\d+) Error\(s\)", log)
    if counted and int(counted.group(1)) and not errors:
        errors.append(f"the checker reported {counted.group(1)} error(s)")
    if not counted:
        errors.append("the checker wrote no summary (it stopped early)")
    return errors, warnings


def run_compliance_checker(fmu, step: float, stop: float, *, workdir=None, timeout: float = 600.0) -> ImporterRun:
    """Run the FMU Compliance Checker on one FMU: ``fmuCheck.linux64 -h STEP -s STOP -n 0``.

    ``-n 0`` writes an output row at every step (by default the checker writes at most 500, and may then
    leave out the row at the stop time).

    Parameters
    ----------
    fmu : str or Path
        A Co-Simulation FMU.
    step : float
        The communication step (``-h``; the checker's own default is stop/500).
    stop : float
        The stop time (``-s``).
    workdir : str or Path, optional
        Where the log (``check.log``), the output (``out.csv``) and the unpacked FMU go (made if need be);
        by default a temporary folder, removed afterwards.
    timeout : float, optional
        Seconds after which the run counts as failed.

    Returns
    -------
    ImporterRun
    """
    path = importer_path(FMUCHECK)
    base = ImporterRun(FMUCHECK[0], Path(fmu), float(step), float(stop))
    if missing := importer_missing(FMUCHECK):
        return replace(base, unavailable=missing)
    with tempfile.TemporaryDirectory(prefix="fmucheck-") as scratch:
        folder = _folder(workdir or scratch)
        log, out = folder / "check.log", folder / "out.csv"
        args = ["-h", repr(float(step)), "-s", repr(float(stop)), "-n", "0", "-o", str(out), "-e", str(log),
                "-t", str(folder), str(fmu)]
        proc, unavailable, failed = _launch(FMUCHECK, path, args, timeout)
        if unavailable or failed:
            return replace(base, unavailable=unavailable, errors=(failed,) if failed else ())
        text = log.read_text(errors="replace") if log.is_file() else proc.stdout + proc.stderr
        errors, warnings = _checker_lines(text)
        _exit_code(errors, "the checker", proc.returncode)
        rows, last, read = _read_output(out)
        return replace(base, errors=tuple(errors + read), warnings=tuple(warnings), last_time=last, rows=rows,
                     log=text)


def run_fmusim(fmu, step: float, stop: float, *, workdir=None, timeout: float = 600.0) -> ImporterRun:
    """Run Reference-FMUs' fmusim on one FMU: ``fmusim --interface-type cs --output-interval STEP --stop-time STOP``.

    Its log level is ``warning``: every line it prints is a warning or worse (the FMU's lines start with
    their status, ``[Discard] t = ...``).

    Parameters
    ----------
    fmu : str or Path
        A Co-Simulation FMU.
    step : float
        The output interval, which is fmusim's communication step.
    stop : float
        The stop time.
    workdir : str or Path, optional
        Where the output (``out.csv``) goes (made if need be); by default a temporary folder, removed
        afterwards.
    timeout : float, optional
        Seconds after which the run counts as failed.

    Returns
    -------
    ImporterRun
    """
    path = importer_path(FMUSIM)
    base = ImporterRun(FMUSIM[0], Path(fmu), float(step), float(stop))
    if missing := importer_missing(FMUSIM):
        return replace(base, unavailable=missing)
    with tempfile.TemporaryDirectory(prefix="fmusim-") as scratch:
        out = _folder(workdir or scratch) / "out.csv"
        args = ["--interface-type", "cs", "--output-interval", repr(float(step)), "--stop-time", repr(float(stop)),
                "--log-level", "warning", "--output-file", str(out), str(fmu)]
        proc, unavailable, failed = _launch(FMUSIM, path, args, timeout)
        if unavailable or failed:
            return replace(base, unavailable=unavailable, errors=(failed,) if failed else ())
        text = proc.stdout + proc.stderr
        errors, warnings = [], []
        for line in filter(None, (line.strip() for line in text.splitlines())):
            status = _FMUSIM_STATUS.match(line)
            if status is None or status.group(1) in _ERRORS:      # fmusim's own complaints have no status
                errors.append(line)
            elif status.group(1) in _WARNINGS:
                warnings.append(line)
        _exit_code(errors, "fmusim", proc.returncode)
        rows, last, read = _read_output(out)
        return replace(base, errors=tuple(errors + read), warnings=tuple(warnings), last_time=last, rows=rows,
                     log=text)


__all__ = ["FIXED_STEP_WARNING", "FMUCHECK", "FMUSIM", "IMPORTERS", "ImporterRun", "bare_environment",
           "importer_missing", "importer_path", "importer_unavailable", "run_compliance_checker", "run_fmusim"]
