"""A card designed on one machine re-checks on another: the example cards designed here are
verified under other OpenBLAS kernels (and 2 threads), where every product, ``expm`` and ``pinv``
the re-check and the consistency comparison recompute is rounded differently."""

from __future__ import annotations

import json
import os
from fractions import Fraction
import subprocess
import sys
from pathlib import Path

import pytest

import uiofmu
from uiofmu.problem import problem_from_data

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = [ROOT / "examples" / f"{n}.toml" for n in ("seed000_example1", "seed000_example1_ltv",
                                                       "seed000_example2_consistent", "seed001_example",
                                                       "seed002_setup2", "seed002_three_modes", "seed003_example",
                                                       "seed003_needs_theta", "functional_uio",
                                                       "functional_without_full_uio")] + \
    [ROOT / "plants" / n / "problem.toml" for n in ("quarter_car", "two_room_building")]
#: Plants of our own where rounding decides the last digits: two unknown inputs nearly collinear
#: (cond(CE) = 7e6, so M = -E (CE)^+ moves by 1.2e-9 between Prescott or Sandybridge and the default
#: kernel), and a dhat matrix that is zero in exact arithmetic (C w = 0.3 * 0.1 - 0.3 * 0.1: exact zero
#: on one kernel, 1.7e-18 on another).
OWN = {
    "near-collinear": {"name": "near-collinear", "plant": {
        "time": "discrete", "dt": 0.1,
        "A": [[0.076, -0.209, -0.165, -0.977], [0.72, 0.458, -0.13, 0.31], [0.112, -0.222, 0.391, -0.124],
              [-0.132, -0.317, 0.182, -0.04]],
        "B": [[0.0], [0.0], [0.0], [0.0]],
        "E": [[-1.729, -1.7289989220000002], [-1.505, -1.5049992779999999], [0.841, 0.841000211],
              [0.129, 0.129000284]],
        "C": [[0.545, -0.607, 0.127, -0.892], [0.841, 0.188, 0.331, 0.411], [-1.011, 0.783, 2.057, -1.638]]},
        "observer": {"family": "lti-uio", "decay": 0.9}},
    "zero-product": {"name": "zero-product", "plant": {
        "time": "discrete", "dt": 0.1, "A": [[0.5, 0.1], [0.0, 0.6]], "B": [[0.0], [1.0]], "E": [[1.0], [0.0]],
        "C": [[0.3, -0.3]], "w": [0.1, 0.1]}, "observer": {"family": "lti-uio", "decay": 0.9}},
}
AVX512 = "avx512f" in Path("/proc/cpuinfo").read_text()
KERNELS = ["Prescott", "Sandybridge", "Haswell"] + (["SkylakeX"] if AVX512 else [])
VERIFY = """
import json, sys
from uiofmu.runtime.card import read_card
from uiofmu.synthesis import verify
out = {}
for path in sys.argv[1:]:
    failed = [c.explain() for c in verify(read_card(path)) if not c.holds]
    out[path] = failed
print(json.dumps(out))
"""


def test_the_plants_of_our_own_are_where_rounding_decides():
    import numpy as np

    C, E = (np.array(OWN["near-collinear"]["plant"][k]) for k in ("C", "E"))
    assert 1e6 < np.linalg.cond(C @ E) < 1e8
    C, w = OWN["zero-product"]["plant"]["C"][0], OWN["zero-product"]["plant"]["w"]
    assert sum(Fraction(c) * Fraction(x) for c, x in zip(C, w)) == 0        # zero in exact arithmetic


@pytest.fixture(scope="module")
def cards(tmp_path_factory):
    folder = tmp_path_factory.mktemp("travel")
    paths = []
    for problem in [uiofmu.load_problem(p) for p in PROBLEMS] + [problem_from_data(d) for d in OWN.values()]:
        card = uiofmu.design(problem)
        path = folder / f"{card.name}.json"
        card.write(path)
        paths.append(str(path))
    return paths


@pytest.mark.parametrize("threads", ["1", "2"])
@pytest.mark.parametrize("kernel", KERNELS)
def test_cards_designed_here_re_check_under_other_kernels(cards, kernel, threads):
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "OPENBLAS_NUM_THREADS": threads}
    res = subprocess.run([sys.executable, "-c", VERIFY, *cards], capture_output=True, text=True, env=env,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    failed = {Path(k).name: v for k, v in json.loads(res.stdout.strip().splitlines()[-1]).items() if v}
    assert not failed, failed
