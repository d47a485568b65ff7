"""The plant's matrix exponential: one algorithm, Padé approximants with scaling and squaring (Higham
2005), in the Python runtime (uiofmu/runtime/matrix_exponential.py) and in the C plant kernel
(``uiofmu_expm`` in uiofmu/fmu/c/kernel_plant.c, driven by tests/c/expm_test.c).

The bound against ``scipy.linalg.expm`` (``E``) is stated in the 1-norm, relative, and grows with the
norm of ``M`` as the forward error of any scaling-and-squaring method does (its condition number
grows with it):

    ||X - E||_1 <= 1e-13 max(1, ||M||_1) ||E||_1

(measured on the matrices below: at most 2.2e-14 max(1, ||M||_1) ||E||_1 for the random ones, 7.4e-15
for the stiff ones, 1.3e-15 for the special ones). The C and the Python exponential take the same
degree, scaling and steps, and differ only by the rounding of their products and of their LU solves
(BLAS and LAPACK against the C loops):

    ||X_C - X_py||_1 <= 2e-15 max(1, ||M||_1) ||X_py||_1

(measured: at most 4.4e-16).
"""

from __future__ import annotations

import subprocess
import zipfile

import numpy as np
import pytest
import scipy.linalg

from cfmu import NEEDS_CC
from conftest import ROOT
from uiofmu.fmu.export import build_plant
from uiofmu.plant import Plant
from uiofmu.runtime.matrix_exponential import MAX_SQUARINGS, THETA, degree_and_scaling, expm

TO_SCIPY = 1e-13
C_TO_PYTHON = 2e-15


def norm1(M) -> float:
    return float(np.abs(M).sum(axis=0).max()) if np.size(M) else 0.0


def random_matrices(seed: int, count: int = 200) -> list:
    """Dense Gaussian matrices of orders 1 to 8 and 1-norms from about 1e-4 to 30."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        k = int(rng.integers(1, 9))
        out.append(rng.normal(size=(k, k)) * 10 ** rng.uniform(-4, 1) / np.sqrt(k))
    return out


def stiff_matrices(seed: int, count: int = 200) -> list:
    """Orders 2 to 8, eigenvalues from -1e-2 to -1e3 (five decades apart at most), not normal: an
    orthogonal similarity of a triangular matrix with Gaussian couplings above its diagonal."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        k = int(rng.integers(2, 9))
        Q, _ = np.linalg.qr(rng.normal(size=(k, k)))
        T = np.diag(-10 ** rng.uniform(-2, 3, size=k)) + np.triu(rng.normal(size=(k, k)), 1)
        out.append(Q @ T @ Q.T)
    return out


#: Matrices whose exponential is known: a rotation generator (exp is the rotation), a nilpotent one
#: (exp is I + N + N^2/2), the zero matrix, and one exactly at each theta_m (the degree changes there).
def special_matrices() -> list:
    w = 40.0
    N = np.triu(np.arange(1.0, 17.0).reshape(4, 4), 1)
    return [np.array([[0.0, w], [-w, 0.0]]), N, np.zeros((3, 3)),
            *(np.diag([theta, -theta / 2]) for theta in THETA.values())]


CASES = {"random": random_matrices(11), "stiff": stiff_matrices(12), "special": special_matrices()}


def _worst(got: list, want: list, matrices: list) -> float:
    """The largest ``||X - E||_1 / (max(1, ||M||_1) ||E||_1)``."""
    return max(norm1(x - e) / (max(1.0, norm1(m)) * norm1(e)) for x, e, m in zip(got, want, matrices))


@pytest.mark.parametrize("case", list(CASES))
def test_the_python_exponential_equals_scipys(case):
    matrices = CASES[case]
    worst = _worst([expm(m) for m in matrices], [scipy.linalg.expm(m) for m in matrices], matrices)
    assert worst <= TO_SCIPY, f"{case}: {worst:.3g}"


def test_known_exponentials():
    w = 40.0
    R = expm(np.array([[0.0, w], [-w, 0.0]]))
    np.testing.assert_allclose(R, [[np.cos(w), np.sin(w)], [-np.sin(w), np.cos(w)]], rtol=0, atol=40 * 1e-14)
    N = np.triu(np.arange(1.0, 17.0).reshape(4, 4), 1)
    np.testing.assert_allclose(expm(N), np.eye(4) + N + N @ N / 2 + N @ N @ N / 6, rtol=1e-15, atol=0)
    assert np.array_equal(expm(np.zeros((3, 3))), np.eye(3))


def test_the_degree_and_scaling_of_higham_2005():
    assert [degree_and_scaling(THETA[m]) for m in (3, 5, 7, 9, 13)] == [(3, 0), (5, 0), (7, 0), (9, 0), (13, 0)]
    assert degree_and_scaling(np.nextafter(THETA[9], np.inf)) == (13, 0)
    assert degree_and_scaling(2 * THETA[13]) == (13, 1)
    assert degree_and_scaling(np.nextafter(2 * THETA[13], np.inf)) == (13, 2)


def test_what_the_python_exponential_refuses():
    assert np.all(np.isnan(expm(np.array([[np.nan, 0.0], [0.0, 1.0]]))))
    assert np.all(np.isnan(expm(np.full((2, 2), 1e308))))                        # its 1-norm overflows
    assert degree_and_scaling(np.finfo(float).max)[1] <= MAX_SQUARINGS           # a finite one never needs more
    assert not np.all(np.isfinite(expm(np.array([[800.0]]))))                     # exp(800) overflows


# -- the C kernel's exponential ----------------------------------------------------------------

@pytest.fixture(scope="module")
def c_expm(tmp_path_factory):
    """``run(matrices) -> list`` of the C kernel's exponentials (None where it refuses)."""
    if NEEDS_CC.args[0]:
        pytest.skip(NEEDS_CC.kwargs["reason"])
    work = tmp_path_factory.mktemp("expm")
    fmu = build_plant(Plant.create([[-1.0]], [[1.0]], [[1.0]], time="continuous"), "one", work / "p.fmu",
                      backend="c")
    src = work / "src"
    with zipfile.ZipFile(fmu) as z:
        for name in z.namelist():
            if name.startswith("sources/"):
                z.extract(name, work)
    (work / "sources").rename(src)
    exe = work / "expm_test"
    files = [ROOT / "tests" / "c" / "expm_test.c",
             *(src / n for n in ("fmi2_plumbing.c", "kernel_util.c", "kernel_plant.c", "design_data.c"))]
    proc = subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", f"-I{src}", "-o", str(exe),
                           *map(str, files), "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stderr.strip() == "", proc.stderr

    def run(matrices: list) -> list:
        text = "\n".join(f"{m.shape[0]} " + " ".join(map(repr, m.ravel().tolist())) for m in matrices)
        out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        lines = out.stdout.splitlines()
        assert len(lines) == len(matrices)
        return [None if line == "refused" else np.array([float.fromhex(v) for v in line.split()]).reshape(m.shape)
                for line, m in zip(lines, matrices)]

    return run


@pytest.mark.parametrize("case", list(CASES))
def test_the_c_exponential_equals_scipys_and_the_pythons(c_expm, case):
    matrices = CASES[case]
    got = c_expm(matrices)
    assert all(x is not None for x in got)
    worst = _worst(got, [scipy.linalg.expm(m) for m in matrices], matrices)
    assert worst <= TO_SCIPY, f"{case}: C against scipy {worst:.3g}"
    worst = _worst(got, [expm(m) for m in matrices], matrices)
    assert worst <= C_TO_PYTHON, f"{case}: C against Python {worst:.3g}"


def test_the_c_exponential_refuses_what_the_python_one_refuses(c_expm):
    matrices = [np.array([[np.nan, 0.0], [0.0, 1.0]]), np.full((2, 2), 1e308), np.array([[800.0]])]
    assert c_expm(matrices) == [None, None, None]
    assert all(not np.all(np.isfinite(expm(m))) for m in matrices)
