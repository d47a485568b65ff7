"""``validate``'s relative difference: the run's largest difference over one scale for the whole run."""

from __future__ import annotations

import math

import numpy as np

from uiofmu.cosim.validate import Validation, _compare


def test_relative_difference_divides_by_one_scale_for_the_whole_run():
    """A difference of 1e-9 at a sample whose outputs are small, in a run whose outputs reach
    1e3: relative 1e-12 (the run's scale), not 1e-9 (that sample's), whatever the order."""
    samples = [(np.array([1e3, 0.0]), np.array([1e3, 0.0])),              # large outputs, no difference
               (np.array([0.5 + 1e-9, 0.1]), np.array([0.5, 0.1]))]         # small outputs, the difference
    for order in (samples, samples[::-1]):
        report = Validation("x.fmu", "observer")
        for got, ref in order:
            _compare(report, got, ref)
        assert report.scale == 1e3
        assert math.isclose(report.max_abs_diff, 1e-9, rel_tol=1e-6)
        assert math.isclose(report.max_rel_diff, 1e-12, rel_tol=1e-6)
        assert report.to_data()["scale"] == 1e3


def test_small_outputs_are_compared_absolutely_and_nan_fails():
    report = Validation("x.fmu", "observer")
    _compare(report, np.array([1e-3 + 1e-13]), np.array([1e-3]))
    assert report.scale == 1.0 and report.max_rel_diff == report.max_abs_diff
    assert report.ok
    _compare(report, np.array([np.nan]), np.array([2.0]))
    assert report.max_rel_diff == math.inf and not report.ok
