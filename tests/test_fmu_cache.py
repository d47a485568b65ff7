"""FMU files are unpacked once per process and found again by their bytes (:mod:`uiofmu.cosim.fmu_cache`):
runs from the files give the results of the first run bit for bit, an instance alive next to another of the
same bytes has its own copy, an FMU that can be instantiated only once per process has its binary unloaded
between instances, and the private folder goes at exit."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from conftest import ROOT, run_cli
from uiofmu.cosim import fmu_cache
from uiofmu.cosim.fmi import Fmu
from uiofmu.cosim.master import cosimulate
from uiofmu.cosim.steps import step_sequence
from uiofmu.runtime.errors import FmuError


@pytest.fixture(scope="module")
def fmus(example1_card, example1_path, tmp_path_factory):
    """Example 1's plant (C) and observer FMUs on both backends."""
    _, card_path = example1_card
    d = tmp_path_factory.mktemp("cache")
    for backend in ("c", "python"):
        assert run_cli("build", card_path, "-o", d / f"obs_{backend}.fmu", "--backend", backend).code == 0
    assert run_cli("plant", example1_path, "-o", d / "plant.fmu", "--backend", "c").code == 0
    return d


def _run(plant, observer, **kw):
    steps = step_sequence("fixed:0.1", 6.0)
    return cosimulate(plant, observer, steps, show_progress=False, **kw)


def _same(a, b) -> None:
    for name in ("times", "h", "x", "xhat", "y", "r", "dhat"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def _modified(path, tmp_path, name, description=None, comment=b""):
    """A copy of an FMU with its model description rewritten by ``description`` and a zip comment."""
    out = tmp_path / name
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            data = src.read(info)
            if description and info.filename == "modelDescription.xml":
                data = description(data.decode()).encode()
            dst.writestr(info, data)
        dst.comment = comment
    return out


@pytest.mark.parametrize("backend", ["c", "python"])
def test_runs_from_the_files_reuse_one_copy_and_agree_bit_for_bit(fmus, backend):
    observer = fmus / f"obs_{backend}.fmu"
    first = _run(fmus / "plant.fmu", observer)
    digest = fmu_cache.digest_of(observer)
    assert digest in fmu_cache.files()
    with Fmu(observer, "probe") as a:
        folder = a._unzipdir
        assert a.slave.dll is not None
    with Fmu(observer, "probe") as b:
        assert b._unzipdir == folder                  # the same copy, binary loaded, serves the next instance
    for _ in range(2):
        _same(_run(fmus / "plant.fmu", observer), first)


def test_two_live_instances_of_the_same_bytes_have_their_own_copies(fmus):
    observer = fmus / "obs_c.fmu"
    with Fmu(observer, "one") as one, Fmu(observer, "two") as two:
        assert one._unzipdir != two._unzipdir
        assert one.slave is not two.slave and one.slave.dll._handle != two.slave.dll._handle
        for fmu, y in ((one, 1.0), (two, -3.0)):
            fmu.initialize(0.0)
            fmu.set("y", [y])
            fmu.set("u", [0.0])
            fmu.step(0.0, 0.1)
        assert not np.array_equal(one.get("xhat"), two.get("xhat"))
    # a run with sensor noise has the observer and its noise-free twin alive at once
    noisy = _run(fmus / "plant.fmu", observer, noise="y=0.01,4")
    _same(noisy, _run(fmus / "plant.fmu", observer))        # the twin's run is the noise-free one
    assert noisy.noise is not None and not np.array_equal(noisy.noise["estimate"], noisy.xhat)


def test_the_bytes_decide_not_the_name(fmus, tmp_path):
    observer = fmus / "obs_c.fmu"
    reference = _run(fmus / "plant.fmu", observer)
    renamed = tmp_path / "renamed.fmu"
    shutil.copyfile(observer, renamed)
    with Fmu(renamed, "renamed") as fmu:
        assert fmu_cache.digest_of(renamed) == fmu_cache.digest_of(observer)
        assert fmu.description is fmu_cache._UNITS[fmu_cache.digest_of(observer)].description
    # other bytes under a name already used: another unit, read and checked afresh
    target = tmp_path / "changing.fmu"
    shutil.copyfile(observer, target)
    _same(_run(fmus / "plant.fmu", target), reference)
    shutil.copyfile(fmus / "plant.fmu", target)
    with pytest.raises(FmuError, match="not an observer built by uiofmu"):
        _run(fmus / "plant.fmu", target)
    with Fmu(target, "plant-now") as fmu:
        assert fmu.has("x") and not fmu.has("xhat")


def test_an_fmu_instantiated_only_once_per_process_is_unloaded_between_instances(fmus, tmp_path):
    once = _modified(fmus / "obs_c.fmu", tmp_path, "once.fmu", lambda text: text.replace(
        'canBeInstantiatedOnlyOncePerProcess="false"', 'canBeInstantiatedOnlyOncePerProcess="true"'))
    reference = _run(fmus / "plant.fmu", fmus / "obs_c.fmu")
    _same(_run(fmus / "plant.fmu", once), reference)
    unit = fmu_cache._UNITS[fmu_cache.digest_of(once)]
    assert unit.once and unit.free and all(copy.slave is None for copy in unit.free)
    folder = unit.free[0].folder
    assert (folder / "modelDescription.xml").is_file()          # the files stay for the next instance
    _same(_run(fmus / "plant.fmu", once), reference)


def test_the_least_recently_used_file_goes_beyond_the_limit(fmus, tmp_path, monkeypatch):
    monkeypatch.setattr(fmu_cache, "MAX_FILES", 2)
    paths = [_modified(fmus / "obs_c.fmu", tmp_path, f"v{i}.fmu", comment=f"variant {i}".encode())
             for i in range(3)]
    folders = []
    for path in paths:
        with Fmu(path, "variant") as fmu:
            folders.append(fmu._unzipdir)
    kept = fmu_cache.files()
    assert len(kept) == 2 and fmu_cache.digest_of(paths[0]) not in kept
    assert not os.path.exists(folders[0]) and os.path.exists(folders[2])


def test_a_broken_file_is_refused_naming_it_and_leaves_nothing(tmp_path):
    bad = tmp_path / "bad.fmu"
    bad.write_bytes(b"not a zip")
    before = set(os.listdir(fmu_cache.folder())) if fmu_cache.folder() else set()
    with pytest.raises(FmuError, match=f"{bad}: not a readable FMU"):
        Fmu(bad, "bad")
    assert set(os.listdir(fmu_cache.folder())) == before
    with pytest.raises(FmuError, match="no such FMU"):
        Fmu(tmp_path / "missing.fmu", "missing")


def test_the_private_folder_goes_at_exit(fmus, tmp_path):
    script = (f"import json, sys\nfrom uiofmu.cosim import fmu_cache\nfrom uiofmu.cosim.fmi import Fmu\n"
              f"fmu = Fmu({str(fmus / 'obs_c.fmu')!r}, 'o')\nfmu.close()\n"
              f"print(json.dumps(str(fmu_cache.folder())))\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    folder = json.loads(proc.stdout)
    assert "uiofmu_fmus_" in folder and not os.path.exists(folder)


def test_a_card_is_re_checked_once_per_content(fmus, tmp_path, monkeypatch):
    import uiofmu.synthesis
    from uiofmu.cosim.master import observer_card

    observer = tmp_path / "obs.fmu"
    shutil.copyfile(fmus / "obs_c.fmu", observer)
    first = observer_card(observer)
    checks = []
    monkeypatch.setattr(uiofmu.synthesis, "recheck", lambda card: checks.append(card) or [])
    again = observer_card(observer)
    assert checks == [] and again.data == first.data and again.data is not first.data
    assert all(np.array_equal(again.matrices[k], first.matrices[k]) for k in first.matrices)
    other = _modified(observer, tmp_path, "other.fmu", comment=b"other bytes, the same card")
    observer_card(other)
    assert len(checks) == 1                     # other bytes: read and re-checked afresh


def test_files_removed_under_the_cache_are_unpacked_again(fmus, tmp_path):
    """A cleaner of the temporary folder may remove the private folder of a long process: the next instance
    unpacks the file again."""
    observer = tmp_path / "obs.fmu"
    shutil.copyfile(fmus / "obs_c.fmu", observer)
    reference = _run(fmus / "plant.fmu", observer)
    shutil.rmtree(fmu_cache.folder())
    _same(_run(fmus / "plant.fmu", observer), reference)
    assert fmu_cache.folder().is_dir() and fmu_cache.digest_of(observer) in fmu_cache.files()


def test_bytes_seen_under_other_limits_are_checked_again(fmus, monkeypatch):
    from uiofmu.cosim import fmi

    observer = fmus / "obs_c.fmu"
    with Fmu(observer, "before"):
        pass
    monkeypatch.setattr(fmi, "MAX_ELEMENTS", 20)
    with pytest.raises(FmuError, match=r"modelDescription.xml has 21 elements.*uiofmu.cosim.fmi.MAX_ELEMENTS"):
        Fmu(observer, "after")
    with pytest.raises(FmuError, match="MAX_ELEMENTS"):
        _run(fmus / "plant.fmu", observer)
