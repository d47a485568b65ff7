"""The same answers on every machine: verdicts, figures and refusals do not depend on the BLAS kernel.

OpenBLAS picks its kernel by the CPU, so another machine rounds differently; ``make test-blas`` runs
this file (and the other numerically sensitive ones) under ``OPENBLAS_CORETYPE`` = Prescott,
Sandybridge, Haswell, SkylakeX (where the CPU has AVX-512) and the default, with 1 and 2 threads.

* Every problem of ``tests/same_answers.py`` (the examples, the robustness reproducers and sample,
  plants at the edge of double precision) gets the check's lines, the design's exit code and the
  figures ``uiofmu design`` prints, or its one-line refusal, exactly as stored in
  ``tests/data/same_answers.txt``.
* ``tests/test_fmus_catalogue.py`` (also run by ``make test-blas``): the catalogue's
  ``fmus/README.md`` regenerates byte for byte.

What is not stored: the digits of an overshoot the design card marks as not determined by the problem
(read off the point the solver stopped at: a point of largest margin, an optimum not reproduced), and the
largest gain's figures; the words saying so are.
"""

from __future__ import annotations

import difflib

import same_answers


def test_every_problem_gets_the_stored_verdict():
    have = same_answers.text()
    want = same_answers.STORED.read_text(encoding="utf-8")
    diff = "\n".join(list(difflib.unified_diff(want.splitlines(), have.splitlines(), "stored", "now",
                                               lineterm="", n=1))[:60])
    assert have == want, ("the verdicts differ from tests/data/same_answers.txt (after a deliberate change: "
                          "python tests/same_answers.py --write)\n" + diff)


def test_the_set_covers_refusals_and_designs_at_the_edge():
    """The stored text is not vacuous: it holds certified designs, refusals for want of an observer,
    and refusals because rounding would decide the verdict."""
    text = same_answers.STORED.read_text(encoding="utf-8")
    assert text.count("design: exit 0") >= 20
    assert text.count("no observer exists") >= 4
    # figures are compared: most designs print an overshoot the problem determines, a few say it does not
    undetermined = text.count("not determined by the problem")
    assert 1 <= undetermined <= text.count("overshoot_bound") - 15
    assert "rounding floor" in text and text.count("## ") == len(same_answers.problems())
    assert text.count("overshoot_bound") >= 12 and "examples/seed000_example1_ltv.toml" in text


def test_blas_threads_are_one_inside_a_design_and_restored_after(monkeypatch):
    """uiofmu limits BLAS to one thread for its small matrices, and gives the user's setting back."""
    from threadpoolctl import threadpool_info, threadpool_limits

    import uiofmu
    import uiofmu.families.lti_uio as lti
    from uiofmu.problem import problem_from_data

    seen = []
    design = lti.design

    def spy(problem, analysis):
        seen.append([pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"])
        return design(problem, analysis)

    monkeypatch.setattr(lti, "design", spy)
    doc = {"name": "dc", "plant": same_answers.DC_MOTOR, "observer": {"family": "lti-uio", "dt": 0.01, "decay": 0.99}}
    with threadpool_limits(limits=2, user_api="blas"):           # at most what OPENBLAS_NUM_THREADS allows
        before = [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]
        uiofmu.design(problem_from_data(doc))
        after = [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]
    assert seen and seen[0] and all(n == 1 for n in seen[0])
    assert after and after == before
