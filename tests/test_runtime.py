"""The reference runtime against a direct simulation of the plant and of the error dynamics."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import uiofmu
from uiofmu.runtime.observer import Runtime, RuntimeInputError
from uiofmu.runtime.schedules import StepRejected


def simulate(card, plant, steps, rng, xhat0):
    """Plant and runtime side by side with random u and d; returns x, xhat, dhat, y histories."""
    rt = Runtime(card, xhat0=xhat0)
    x = plant.x0.copy()
    s = plant.sampled(card.dt)
    xs, xh, dh, ds, rs = [], [], [], [], []
    for _ in range(steps):
        u, d = rng.normal(size=plant.m), rng.normal(size=plant.q)
        y = plant.C @ x
        rt.set_y(y)
        rt.set_u(u)
        xs.append(x.copy())
        xh.append(rt.xhat().copy())
        dh.append(rt.dhat().copy())
        rs.append(rt.residual().copy())
        ds.append(d)
        rt.step(card.dt)
        x = s.A @ x + s.B @ u + s.E @ d + s.w
    return map(np.array, (xs, xh, dh, ds, rs))


@pytest.mark.parametrize("seed", range(3))
def test_error_follows_N_exactly(example1_card, seed):
    card, _ = example1_card
    rng = np.random.default_rng(seed)
    plant = uiofmu.Plant.create(**{k: card.data["problem"]["plant"][k] for k in ("A", "B", "E", "C")},
                                dt=0.1, x0=rng.normal(size=2) * 5)
    xhat0 = rng.normal(size=2)
    xs, xh, dh, ds, rs = simulate(card, plant, 300, rng, xhat0)
    N = card.matrices["N"]
    e = xs[0] - xhat0
    for k in range(len(xs)):
        np.testing.assert_allclose(xs[k] - xh[k], e, rtol=1e-9, atol=1e-12 * np.linalg.norm(xs[0] - xhat0))
        e = N @ e
    # residual r = C e
    np.testing.assert_allclose(rs, (xs - xh) @ plant.C.T, atol=1e-12)
    # dhat_k = d_{k-1} + (CE)^+ C A e_{k-1}
    CEp = np.linalg.pinv(plant.C @ plant.E)
    expect = ds[:-1] + (xs[:-1] - xh[:-1]) @ (CEp @ plant.C @ plant.A).T
    np.testing.assert_allclose(dh[1:], expect, atol=1e-9)
    assert np.all(dh[0] == 0)


def test_affine_term_is_decoupled():
    plant = uiofmu.Plant.create([[0.5, 0.1], [0.0, 0.3]], [[1.0, 1.0]], [[1.0], [0.0]], dt=1.0, w=[0.4, -0.2])
    card = uiofmu.design(uiofmu.make_problem(plant, "lti-uio", decay=0.6))
    rng = np.random.default_rng(1)
    xs, xh, *_ = simulate(card, plant, 60, rng, np.array([3.0, -2.0]))
    err = np.linalg.norm(xs - xh, axis=1)
    assert err[-1] < 1e-10 * err[0]


def test_state_round_trip_and_reset(example1_card):
    card, _ = example1_card
    rt = Runtime(card, xhat0=[1.0, 2.0])
    for k in range(5):
        rt.set_y([np.sin(k)])
        rt.set_u([np.cos(k)])
        rt.step(0.1)
    saved = rt.get_state()
    outs = []
    for _ in range(2):
        rt.set_state(saved)
        trace = []
        for k in range(5):
            rt.set_y([0.1 * k])
            trace.append(rt.xhat().copy())
            rt.step(0.1)
        outs.append(np.array(trace))
    assert np.array_equal(outs[0], outs[1])
    rt.reset()
    assert rt.k == 0 and rt.xhat().tolist() == [1.0, 2.0]


def test_bad_steps_and_inputs(example1_card):
    card, _ = example1_card
    rt = Runtime(card)
    with pytest.raises(StepRejected, match="designed for steps of dt = 0.1 s and received h = 0.2 s"):
        rt.step(0.2)
    for h in (0.0, -0.1, float("nan")):
        with pytest.raises(RuntimeInputError, match="expected h > 0"):
            rt.step(h)
    rt.set_y([float("nan")])
    with pytest.raises(RuntimeInputError, match=r"input y\[1\] = nan"):
        rt.step(0.1)
    assert rt.k == 0


def test_runtime_does_not_import_the_solver():
    code = ("import sys, uiofmu.runtime.observer, uiofmu.runtime.card; "
            "bad = [m for m in ('cvxpy', 'clarabel', 'scipy', 'matplotlib') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
