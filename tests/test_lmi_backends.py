"""The direct conic assembly against the straightforward cvxpy formulation of the same LMIs."""

from __future__ import annotations

import numpy as np
import pytest

import uiofmu
from uiofmu.conic import TRACE_OPS, Affine, ParamAffine
from uiofmu.decoupling import projector
from uiofmu.families import lti_uio, ltv_auid, sampled_data
from uiofmu.lmi import NUMPY_OPS, search
from tests.conftest import EXAMPLES, ROOT


def systems():
    """(label, LmiSystem factory, parameter, feasible value, infeasible value) on the seed examples."""
    ex1 = uiofmu.load_problem(EXAMPLES / "seed000_example1.toml")
    s1 = ex1.plant.sampled(0.1)
    PA = projector(ex1.plant.C, s1.E) @ s1.A
    building = uiofmu.load_problem(ROOT / "plants" / "two_room_building")
    samples = [building.plant.sampled(h) for h in building.options.intervals]
    ltv = uiofmu.load_problem(EXAMPLES / "seed000_example1_ltv.toml")
    _, A1, A2, S1 = ltv_auid._vertices(ltv.plant.sampled(0.1), ltv.plant.C, 0.9)
    return [
        ("lti-uio", lambda b: _with(lti_uio._lmis(PA, ex1.plant.C), b), "rho2", 0.995 ** 2, 0.985 ** 2),
        ("sampled-data", lambda b: _with(sampled_data._lmis(samples, building.plant.C), b), "c", 1 - 0.05, 1 - 0.2),
        ("ltv-auid", lambda b: _with(ltv_auid._lmis(A1, A2, S1, ltv.plant.C, 0.01), b), "tau1", 0.91, 1.2),
    ]


def _fields(system):
    return {k: getattr(system, k) for k in ("name", "variables", "parameters", "build", "objective", "margin",
                                            "solver_tol")}


def _with(system, backend):
    return system.__class__(**{**_fields(system), "backend": backend})


@pytest.mark.parametrize("index", range(3))
def test_same_verdicts_on_feasible_and_infeasible_cases(index):
    label, make, param, good, bad = systems()[index]
    for backend in ("direct", "cvxpy"):
        system = make(backend)
        assert system.solve(**{param: good}).verified, (label, backend)
        assert not system.solve(**{param: bad}).verified, (label, backend)


def test_max_searches_agree_within_the_tolerance():
    label, make, param, good, bad = systems()[1]          # the building: alpha searched over c = 1 - alpha
    limit = 1 - 0.955997 ** 2
    found = {b: search(make(b), param, 1e-3 * limit, limit, tol=1e-4 * limit, transform=lambda a: 1 - a)
             for b in ("direct", "cvxpy")}
    assert abs(found["direct"].value - found["cvxpy"].value) <= 2e-4 * limit
    assert found["direct"].solution.verified and found["cvxpy"].solution.verified


def test_trace_equals_numpy_evaluation():
    """The traced affine map, evaluated at a random point, equals the numpy build there."""
    _, make, param, good, _ = systems()[1]
    system = make("direct")
    rng = np.random.default_rng(0)
    x = rng.normal(size=system._conic.nvar)
    values = system._conic.unpack(x)
    traced = system.build({k: Affine.variable(k, s) for k, s in system.variables.items()},
                          {param: ParamAffine(0.0, {param: 1.0})}, TRACE_OPS)
    direct = system.build(values, {param: good}, NUMPY_OPS)
    for t, d in zip(traced, direct):
        got = sum(c for k, c in t.matrix.const.items() if k is None) if t.matrix.const else 0.0
        got = got + sum(good * c for k, c in t.matrix.const.items() if k == param)
        for (k, var), T in t.matrix.coef.items():
            seg = x[system._conic.offsets[var]:system._conic.offsets[var] + system._conic.sizes[var]]
            got = got + (good if k == param else 1.0) * np.einsum("ijv,v->ij", T, seg)
        np.testing.assert_allclose(got, np.asarray(d.matrix, dtype=float), atol=1e-12)
