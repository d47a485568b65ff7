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
    """Both backends verify the feasible value, refuse the infeasible one, and name the
    solver's answers with the same (cvxpy's) status words."""
    label, make, param, good, bad = systems()[index]
    statuses = {}
    for backend in ("direct", "cvxpy"):
        system = make(backend)
        ok, refused = system.solve(**{param: good}), system.solve(**{param: bad})
        assert ok.verified, (label, backend)
        assert not refused.verified, (label, backend)
        statuses[backend] = (ok.status, refused.status)
    assert statuses["direct"] == statuses["cvxpy"], (label, statuses)
    assert statuses["direct"][1] in ("infeasible", "infeasible_inaccurate"), (label, statuses)


CVXPY_STATUSES = ("optimal", "optimal_inaccurate", "infeasible", "infeasible_inaccurate", "unbounded",
                  "unbounded_inaccurate", "user_limit", "solver_error")


def test_direct_backend_speaks_cvxpys_status_words():
    """Every CLARABEL status comes out of the direct backend in cvxpy's words (its CLARABEL
    interface's mapping); only a proof of infeasibility counts as infeasible, not an "almost"."""
    import clarabel

    from uiofmu.conic import cvxpy_status
    from uiofmu.lmi import INFEASIBLE

    names = [s for s in dir(clarabel.SolverStatus) if not s.startswith("_")]
    assert {"Solved", "PrimalInfeasible", "AlmostPrimalInfeasible", "NumericalError"} <= set(names)
    for name in names:
        status = cvxpy_status(getattr(clarabel.SolverStatus, name))
        assert status.split(":")[0] in CVXPY_STATUSES, (name, status)
        assert cvxpy_status(name) == status
    expected = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate", "PrimalInfeasible": "infeasible",
                "AlmostPrimalInfeasible": "infeasible_inaccurate", "DualInfeasible": "unbounded",
                "AlmostDualInfeasible": "unbounded_inaccurate", "MaxIterations": "user_limit",
                "MaxTime": "user_limit", "NumericalError": "solver_error: CLARABEL answered NumericalError",
                "InsufficientProgress": "solver_error: CLARABEL answered InsufficientProgress"}
    assert {k: cvxpy_status(k) for k in expected} == expected
    assert cvxpy_status("SomethingNew") == "solver_error: CLARABEL answered SomethingNew"
    assert INFEASIBLE == ("infeasible",)


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


@pytest.mark.parametrize("index", range(3))
def test_conic_data_equals_numpy_evaluation(index):
    """CLARABEL's slack ``s = b - A x`` at a random point and parameter value is, cone by cone,
    the LMI evaluated with numpy: the scaled upper triangle of ``sym(F) - margin I`` (column
    by column) for a strict LMI, ``sym(F)`` for a non-strict one, ``-F`` for an equality."""
    _, make, param, good, _ = systems()[index]
    system = make("direct")
    problem = system._conic
    x = np.random.default_rng(index).normal(size=problem.nvar)
    A, b = problem.data({param: good})
    slack = b - A @ x
    expected = []
    for lmi in system.build(problem.unpack(x), {param: good}, NUMPY_OPS):
        F = np.asarray(lmi.matrix, dtype=float)
        if lmi.equality:
            expected.append(-F.ravel())
            continue
        S = 0.5 * (F + F.T) - (system.margin if lmi.strict else 0.0) * np.eye(len(F))
        i, j = np.tril_indices(len(F))      # S[j, i]: the upper triangle, column by column
        expected.append(np.where(i == j, 1.0, np.sqrt(2.0)) * S[j, i])
    np.testing.assert_allclose(slack, np.concatenate(expected), atol=1e-12)


def test_card_records_where_the_design_time_went(building_path, cli, tmp_path):
    """The card's timing adds up: CLARABEL and the LMI assembly are parts of the total, the
    solves are the search's, and ``uiofmu design`` prints them."""
    res = cli("design", building_path, "-o", tmp_path / "b.json")
    assert res.code == 0, res.err
    card = uiofmu.read_card(tmp_path / "b.json")
    t = card.data["timing"]
    assert t["backend"] == "direct"
    assert t["solves"] >= card.data["search"]["solves"] >= 1      # the search's values, then the point kept
    assert 0 < t["solver_s"] and 0 < t["lmi_assembly_s"]
    assert t["solver_s"] + t["lmi_assembly_s"] < t["total_s"]
    assert card.data["search"]["seconds"] < t["total_s"]
    line = next(x for x in res.out.splitlines() if x.strip().startswith("time"))
    assert f"CLARABEL {t['solver_s'] * 1e3:.1f} ms ({t['solves']} solve(s))" in line


def test_edge_cases_of_the_assembly():
    """A parameter times a variable, a constant LMI, an LMI whose coefficients cancel, no LMI
    at all, and a non-square matrix (refused with its shape)."""
    from uiofmu.lmi import Lmi, LmiSystem

    scaled = LmiSystem("scaled", {"P": ("symmetric", 2)}, {"a": 1.0},
                       lambda v, p, o: [Lmi("P > I", v["P"] - o.eye(2)),
                                        Lmi("a P <= 3 I", 3 * o.eye(2) - p["a"] * v["P"], strict=False)])
    assert scaled.solve(a=2.0).verified and not scaled.solve(a=4.0).verified
    for build in (lambda v, p, o: [Lmi("constant", np.eye(2))],
                  lambda v, p, o: [Lmi("cancelled", 0.0 * v["P"] + o.eye(2))],
                  lambda v, p, o: []):
        assert LmiSystem("edge", {"P": ("symmetric", 2)}, {}, build).solve().verified
    with pytest.raises(ValueError, match="must be square, found 2x1"):
        LmiSystem("non-square", {"P": ("symmetric", 2)}, {}, lambda v, p, o: [Lmi("F", v["P"] @ np.ones((2, 1)))])


def test_systems_of_one_structure_share_one_traced_form():
    """Two systems of the same LMIs and data share one traced conic form (and its largest-margin forms), whose
    data equal a form traced afresh; other data, even a zero of the other sign, get their own."""
    from uiofmu.conic import ConicProblem

    ex1 = uiofmu.load_problem(EXAMPLES / "seed000_example1.toml")
    s1 = ex1.plant.sampled(0.1)
    C, PA = ex1.plant.C, projector(ex1.plant.C, s1.E) @ s1.A
    first, second = lti_uio._lmis(PA, C), lti_uio._lmis(PA.copy(), C.copy())
    assert second._conic is first._conic
    fresh = ConicProblem(first.variables, first.parameters, first.build, first.objective, first.margin)
    for got, want in zip(first._conic.data({"rho2": 0.97}), fresh.data({"rho2": 0.97})):
        assert np.array_equal(got.toarray() if hasattr(got, "toarray") else got,
                              want.toarray() if hasattr(want, "toarray") else want)
    a, b = first.largest_margin(rho2=0.995 ** 2), second.largest_margin(rho2=0.995 ** 2)
    assert a.verified and b.verified and a.relative_margin == b.relative_margin
    assert all(np.array_equal(a.values[k], b.values[k]) for k in a.values)
    other = PA.copy()
    other[0, 0] += 1e-3
    signed = PA.copy()
    signed[PA == 0.0] = -0.0
    assert (PA == 0.0).any()
    for data in (other, signed):
        assert lti_uio._lmis(data, C)._conic is not first._conic
    assert lti_uio._lmis(PA, C, gain_cap=10.0)._conic is not first._conic


def test_fingerprints_tell_the_data_apart():
    """Equal data give equal fingerprints; a zero's sign, a number's type and an array's shape or dtype do not;
    anything else is refused."""
    from uiofmu.conic import fingerprint

    assert fingerprint([np.eye(2), 0.5, None, "x"]) == fingerprint([np.eye(2).copy(), 0.5, None, "x"])
    assert fingerprint(np.zeros(2)) != fingerprint(-np.zeros(2))
    assert fingerprint(np.zeros(2)) != fingerprint(np.zeros((2, 1)))
    assert fingerprint(np.zeros(2)) != fingerprint(np.zeros(2, dtype=np.float32))
    assert len({fingerprint(1), fingerprint(1.0), fingerprint(True)}) == 3
    assert fingerprint(0.0) != fingerprint(-0.0)
    assert fingerprint((1, 2)) != fingerprint([1, 2])
    with pytest.raises(TypeError, match="no fingerprint of a object"):
        fingerprint(object())


@pytest.mark.parametrize("path", ["plants/two_room_building", "examples/seed002_three_modes.toml"])
def test_a_design_made_again_is_the_same_card(path):
    """A design made again in the same process (its LMIs traced once) is the same card, timings aside, as the
    first, whose LMIs were traced afresh."""
    import json

    from uiofmu import conic

    problem = uiofmu.load_problem(ROOT / path)
    conic._TRACED.clear()
    first = uiofmu.design(problem)
    kept = len(conic._TRACED)
    again = uiofmu.design(problem)
    assert kept >= 2 and len(conic._TRACED) == kept            # the decay's LMIs and the noise lemma's, reused
    assert _timeless(json.loads(again.to_json())) == _timeless(json.loads(first.to_json()))


def _timeless(data):
    """A card's data without its times (``timing``, and every ``*_s`` or ``seconds`` entry)."""
    if isinstance(data, dict):
        return {k: _timeless(v) for k, v in data.items() if k != "timing" and not k.endswith("_s") and k != "seconds"}
    return [_timeless(v) for v in data] if isinstance(data, list) else data
