"""The FMU catalogue ``fmus/README.md`` is what ``make fmus`` writes (issue 20).

The fast tests regenerate the README from the designed cards and the ports and experiments they
declare (design is deterministic, numbers have 4 significant digits) and compare it with the file in
git, except for the column of checks, which records what ``make fmus`` ran: that column is read back
from the file, and may only claim that every check passed. The slow test runs ``make fmus`` into a
temporary folder: exit 0 (every FMU validated, run alone in fmpy and with its plant in our master
and ecospy) and a README identical to the one in git.
"""

from __future__ import annotations

import difflib
import subprocess
import sys

import pytest

from conftest import ROOT

README = ROOT / "fmus" / "README.md"


@pytest.fixture(scope="module")
def catalogue():
    pytest.importorskip("mujoco")             # the MuJoCo plant's row reads its spec
    from uiofmu import catalogue as cat

    return cat.describe(ROOT)


def _diff(have: str, want: str) -> str:
    lines = difflib.unified_diff(have.splitlines(), want.splitlines(), "fmus/README.md", "regenerated", lineterm="",
                                 n=1)
    return "\n".join(list(lines)[:40])


def test_readme_matches_the_designs(catalogue):
    from uiofmu.catalogue import recorded_checks, render

    text = README.read_text(encoding="utf-8")
    recorded = recorded_checks(text)
    assert set(recorded) == {row.file for row in catalogue.rows}, "the README's FMUs differ from the catalogue's"
    want = render(catalogue, recorded)
    assert text == want, ("fmus/README.md is stale: run `make fmus` (or `.venv/bin/python examples/build_fmus.py`)"
                          "\n" + _diff(text, want))


def test_readme_records_only_passed_checks(catalogue):
    """Every FMU was validated and run in our master, fmpy and ecospy (equal to our master where comparable, not
    with a delayed observer or a plant whose inputs feed through;
    ``not run`` only when ecospy is not importable), as ``make fmus`` ran it."""
    from uiofmu.catalogue import check_text, feeds_through, recorded_checks

    recorded = recorded_checks(README.read_text(encoding="utf-8"))
    # ecospy passes the plant's outputs with the previous inputs: ydot of a delayed observer, y where u or d
    # feed through
    uncompared = {row.file for d in catalogue.designs if d.card.kernel == "delayed" or feeds_through(d.card)
                  for row in (d.observer, d.plant)}
    for row in catalogue.rows:
        allowed = {check_text({"validate": "ok", "master": "ok", "fmpy": "ok", "ecospy": ecospy}, row.limited)
                   for ecospy in (("ran", "not run") if row.file in uncompared else ("equal", "not run"))}
        assert recorded[row.file] in allowed, f"{row.file}: {recorded[row.file]!r}, expected one of {allowed}"


def test_every_example_of_every_family_has_its_pair(catalogue):
    from uiofmu.catalogue import FAMILIES, MUJOCO_FILE

    families = {d.card.family for d in catalogue.designs}
    assert families == set(FAMILIES)
    for d in catalogue.designs:
        assert d.observer.partners[0] == d.plant.file and d.plant.partners == [d.observer.file]
        assert d.observer.experiment is not None and d.plant.experiment is not None
        spec = d.observer.experiment                # a whole number of steps: fmpy ends on the stop time
        steps = spec["stopTime"] / spec["stepSize"]
        assert abs(steps - round(steps)) < 1e-9 * steps, d.observer.file
    assert {d.example.key for d in catalogue.designs if MUJOCO_FILE in d.observer.partners} == \
        {"quarter-car", "quarter-car-ltv"}


def test_readme_has_no_machine_specific_text():
    text = README.read_text(encoding="utf-8")
    assert str(ROOT) not in text and "/tmp" not in text and "/home" not in text


def test_numbers_are_rounded():
    from uiofmu.catalogue import num, round_text

    assert [num(x) for x in (600000.0, 1.2916666666666667, 4.448515066881701e-05, 0.9901, 64.00000000068)] == \
        ["600000", "1.292", "4.449e-05", "0.9901", "64"]
    assert round_text("gx_k = G x_(k-1) from k = 3; 0.99498743710662 and 1e-09") == \
        "gx_k = G x_(k-1) from k = 3; 0.995 and 1e-09"


@pytest.mark.slow
def test_make_fmus_passes_and_writes_the_same_readme(tmp_path):
    """``make fmus`` into a temporary folder (about a minute): exit 0 and the README in git."""
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "build_fmus.py"), "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    have, want = README.read_text(encoding="utf-8"), (tmp_path / "README.md").read_text(encoding="utf-8")
    assert have == want, "make fmus writes another README:\n" + _diff(have, want)
