"""Direct conic assembly of LMI systems for CLARABEL, without cvxpy's canonicalisation.

An LMI system is written once as ``build(v, p, ops)`` (see :mod:`uiofmu.lmi`). Called with
:class:`Affine` variables and :class:`ParamAffine` parameters, the same function traces every
LMI as an affine map of the variables, with dense coefficient tensors per variable (the blocks
are small; there are many of them). :class:`ConicProblem` turns the traced LMIs into CLARABEL's
form ``A x + s = b``, ``s`` in zero and PSD-triangle cones, once; a solve for new parameter
values only adds the parameter's sparse part and calls the solver.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

SQRT2 = math.sqrt(2.0)


class ParamAffine:
    """``const + sum_p coef_p * p``: a scalar affine in the parameters."""

    __array_ufunc__ = None

    def __init__(self, const: float = 0.0, coef: dict | None = None):
        self.const = float(const)
        self.coef = dict(coef or {})

    def _lift(self, other):
        return other if isinstance(other, ParamAffine) else ParamAffine(float(other))

    def __add__(self, other):
        if isinstance(other, Affine):
            return other + self
        o = self._lift(other)
        coef = dict(self.coef)
        for k, v in o.coef.items():
            coef[k] = coef.get(k, 0.0) + v
        return ParamAffine(self.const + o.const, coef)

    __radd__ = __add__

    def __neg__(self):
        return ParamAffine(-self.const, {k: -v for k, v in self.coef.items()})

    def __sub__(self, other):
        return self + (-self._lift(other))

    def __rsub__(self, other):
        return self._lift(other) - self

    def __mul__(self, other):
        if isinstance(other, Affine):
            return other.scale(self)
        if isinstance(other, ParamAffine):
            raise TypeError("a product of two parameters is not affine")
        return ParamAffine(self.const * other, {k: v * other for k, v in self.coef.items()})

    __rmul__ = __mul__


class Affine:
    """A matrix expression affine in the variables (and, term by term, in one parameter).

    ``const[key]`` is an (m, n) array and ``coef[(key, var)]`` an (m, n, size(var)) tensor,
    where ``key`` is None or a parameter name (the term is multiplied by that parameter).
    """

    __array_ufunc__ = None

    def __init__(self, shape, const=None, coef=None):
        self.shape = tuple(shape)
        self.const = const or {}
        self.coef = coef or {}

    # -- construction ------------------------------------------------------------------
    @classmethod
    def variable(cls, name: str, spec) -> "Affine":
        """The variable ``name`` of spec ``("symmetric", n) | ("matrix", (r, c)) | ("scalar",)``."""
        if spec[0] == "symmetric":
            n = spec[1]
            T = np.zeros((n, n, n * (n + 1) // 2))
            idx = 0
            for j in range(n):
                for i in range(j + 1):
                    T[i, j, idx] = T[j, i, idx] = 1.0
                    idx += 1
            return cls((n, n), coef={(None, name): T})
        r, c = (1, 1) if spec[0] == "scalar" else spec[1]
        return cls((r, c), coef={(None, name): np.eye(r * c).reshape(r, c, r * c)})

    def _map(self, fconst, fcoef, shape) -> "Affine":
        return Affine(shape, {k: fconst(v) for k, v in self.const.items()},
                      {k: fcoef(v) for k, v in self.coef.items()})

    # -- algebra -----------------------------------------------------------------------
    def __matmul__(self, other):
        if isinstance(other, Affine):
            raise TypeError("a product of two variables is not affine")
        B = np.asarray(other, dtype=float)
        return self._map(lambda c: c @ B, lambda T: np.einsum("ijv,jk->ikv", T, B), (self.shape[0], B.shape[1]))

    def __rmatmul__(self, other):
        A = np.asarray(other, dtype=float)
        return self._map(lambda c: A @ c, lambda T: np.einsum("ij,jkv->ikv", A, T), (A.shape[0], self.shape[1]))

    @property
    def T(self) -> "Affine":
        return self._map(lambda c: c.T, lambda T: T.transpose(1, 0, 2), self.shape[::-1])

    def _combine(self, other, sign: float) -> "Affine":
        """``self + sign * other`` without intermediate copies."""
        if isinstance(other, ParamAffine):
            if other.coef:
                raise TypeError("add a parameter times a matrix, not a bare parameter")
            other = other.const
        if not isinstance(other, Affine):
            arr = np.broadcast_to(np.asarray(other, dtype=float), self.shape)
            other = Affine(self.shape, {None: np.array(arr)})
        if other.shape != self.shape:
            raise ValueError(f"shape mismatch {self.shape} + {other.shape}")
        const = dict(self.const)
        for k, v in other.const.items():
            const[k] = const[k] + sign * v if k in const else sign * v
        coef = dict(self.coef)
        for k, v in other.coef.items():
            coef[k] = coef[k] + sign * v if k in coef else sign * v
        return Affine(self.shape, const, coef)

    def __add__(self, other):
        return self._combine(other, 1.0)

    __radd__ = __add__

    def __neg__(self):
        return self._map(lambda c: -c, lambda T: -T, self.shape)

    def __sub__(self, other):
        return self._combine(other, -1.0)

    def __rsub__(self, other):
        return (-self) + other

    def scale(self, factor: ParamAffine) -> "Affine":
        """``factor * self`` with ``factor`` affine in the parameters."""
        if any(k is not None for k in self.const) or any(k[0] is not None for k in self.coef):
            raise TypeError("a parameter times a parametric term is not affine")
        out = self._map(lambda c: factor.const * c, lambda T: factor.const * T, self.shape)
        for p, a in factor.coef.items():
            for k, v in self.const.items():
                out.const[p] = out.const.get(p, 0.0) + a * v
            for (_, var), T in self.coef.items():
                key = (p, var)
                out.coef[key] = out.coef[key] + a * T if key in out.coef else a * T
        return out

    def __mul__(self, other):
        if isinstance(other, ParamAffine):
            return self.scale(other)
        arr = np.asarray(other, dtype=float)
        if arr.ndim == 0:
            return self._map(lambda c: c * arr, lambda T: T * arr, self.shape)
        if self.shape != (1, 1):
            raise TypeError("only a scalar expression may multiply a matrix")
        return Affine(arr.shape, {k: v[0, 0] * arr for k, v in self.const.items()},
                      {k: arr[:, :, None] * T[0, 0][None, None, :] for k, T in self.coef.items()})

    __rmul__ = __mul__


def bmat(rows) -> Affine:
    """Block matrix of Affine and constant blocks (blocks never overlap, so each is assigned)."""
    heights = [next(b.shape[0] for b in row if hasattr(b, "shape")) for row in rows]
    widths = [next(row[j].shape[1] for row in rows if hasattr(row[j], "shape")) for j in range(len(rows[0]))]
    m, n = sum(heights), sum(widths)
    const, coef = {}, {}
    r0 = 0
    for row, h in zip(rows, heights):
        c0 = 0
        for block, w in zip(row, widths):
            if isinstance(block, Affine):
                for k, v in block.const.items():
                    if k not in const:
                        const[k] = np.zeros((m, n))
                    const[k][r0:r0 + h, c0:c0 + w] = v
                for k, T in block.coef.items():
                    dest = coef.get(k)
                    if dest is None:
                        dest = coef[k] = np.zeros((m, n, T.shape[2]))
                    dest[r0:r0 + h, c0:c0 + w] = T
            else:
                arr = np.asarray(block, dtype=float)
                if arr.any():
                    if None not in const:
                        const[None] = np.zeros((m, n))
                    const[None][r0:r0 + h, c0:c0 + w] = arr
            c0 += w
        r0 += h
    return Affine((m, n), const, coef)


def _sym(M):
    return 0.5 * (M + M.T)


TRACE_OPS = SimpleNamespace(bmat=bmat, eye=np.eye, zeros=np.zeros, sym=_sym)


@lru_cache(maxsize=64)
def _svec_index(n: int):
    """Rows, columns and scales of the upper triangle, column by column (CLARABEL's PSD triangle)."""
    ii, jj = np.triu_indices(n)
    order = np.lexsort((ii, jj))
    ii, jj = ii[order], jj[order]
    return ii, jj, np.where(ii == jj, 1.0, SQRT2)


class ConicProblem:
    """The traced LMIs of a system as CLARABEL data, assembled once.

    Parameters
    ----------
    variables : dict
        Variable specs, as for :class:`uiofmu.lmi.LmiSystem`.
    parameters : dict
        Parameter names (values are given per solve).
    build : callable
        The LMI system's ``build``.
    objective : callable or None
        ``objective(v)``, traced to a 1x1 Affine.
    margin : float
        Strictness margin.
    """

    def __init__(self, variables: dict, parameters: dict, build, objective, margin: float):
        import clarabel

        self._clarabel = clarabel
        self.specs = variables
        self.offsets, self.sizes = {}, {}
        total = 0
        traced = {}
        for name, spec in variables.items():
            var = Affine.variable(name, spec)
            traced[name] = var
            self.offsets[name] = total
            self.sizes[name] = next(iter(var.coef.values())).shape[2]
            total += self.sizes[name]
        self.nvar = total
        params = {k: ParamAffine(0.0, {k: 1.0}) for k in parameters}
        lmis = build(traced, params, TRACE_OPS)
        rows = {}      # parameter key -> (row, col, val) lists of A
        b_parts = []   # (parameter key, first row, values) of b
        self.cones = []
        r = 0
        for lmi in lmis:
            F = lmi.matrix
            if not isinstance(F, Affine):
                F = Affine(np.shape(F), {None: np.asarray(F, dtype=float)})
            if lmi.equality:
                m = F.shape[0] * F.shape[1]
                sel = (np.repeat(np.arange(F.shape[0]), F.shape[1]), np.tile(np.arange(F.shape[1]), F.shape[0]))
                tsel = sel
                scale, sign_a, sign_b = np.ones(m), 1.0, -1.0
                self.cones.append(clarabel.ZeroConeT(m))
                shift = 0.0
            else:
                n = F.shape[0]
                ii, jj, scale = _svec_index(n)
                sel = (ii, jj)
                tsel = (jj, ii)                  # the symmetric part: (F + F') / 2 entry by entry
                m = len(ii)
                sign_a, sign_b = -1.0, 1.0
                self.cones.append(clarabel.PSDTriangleConeT(n))
                shift = margin if lmi.strict else 0.0
            half = (0.5 * sign_a) * scale[:, None]
            for key, T in F.coef.items():
                block = (T[sel] + T[tsel]) * half
                rows.setdefault(key[0], []).append((r, self.offsets[key[1]], block))
            consts = dict(F.const)
            if shift:
                consts[None] = consts.get(None, np.zeros(F.shape)) - shift * np.eye(F.shape[0])
            for key, c in consts.items():
                b_parts.append((key, r, sign_b * 0.5 * (c[sel] + c[tsel]) * scale))
            r += m
        self.nrows = r
        self.A = {key: self._sparse(blocks, r) for key, blocks in rows.items()}
        self.b = {}
        for key, start, vec in b_parts:
            self.b.setdefault(key, np.zeros(r))[start:start + len(vec)] += vec
        self.q = np.zeros(self.nvar)
        if objective is not None:
            obj = objective(traced)
            for (key, var), T in obj.coef.items():
                self.q[self.offsets[var]:self.offsets[var] + self.sizes[var]] += T[0, 0]
        self.P = sp.csc_matrix((self.nvar, self.nvar))

    def _sparse(self, blocks: list, nrows: int):
        """One CSC matrix from dense blocks ``(first row, first column, block)``, zeros dropped.

        The row and column of every entry are computed for all blocks at once."""
        sizes = np.array([b.size for _, _, b in blocks])
        widths = np.repeat(np.array([b.shape[1] for _, _, b in blocks]), sizes)
        local = np.arange(sizes.sum()) - np.repeat(np.cumsum(sizes) - sizes, sizes)
        rows = np.repeat(np.array([r for r, _, _ in blocks]), sizes) + local // widths
        cols = np.repeat(np.array([c for _, c, _ in blocks]), sizes) + local % widths
        vals = np.concatenate([b.ravel() for _, _, b in blocks])
        keep = vals != 0.0
        return sp.csc_matrix((vals[keep], (rows[keep], cols[keep])), shape=(nrows, self.nvar))

    def solve(self, params: dict, tol: float):
        """Solve for the parameter values; returns ``(values or None, status, solver_time)``.

        ``solver_time`` is the wall time spent in CLARABEL's calls: its setup (presolve, KKT
        initialisation, equilibration) and its interior-point iterations."""
        clarabel = self._clarabel
        A = self.A.get(None, sp.csc_matrix((self.nrows, self.nvar)))
        b = self.b.get(None, np.zeros(self.nrows)).copy()
        for k, v in params.items():
            if k in self.A:
                A = A + v * self.A[k]
            if k in self.b:
                b += v * self.b[k]
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_feas = settings.tol_gap_abs = settings.tol_gap_rel = tol
        A = sp.csc_matrix(A)
        t0 = time.perf_counter()                      # CLARABEL's own time: its setup and its solve
        sol = clarabel.DefaultSolver(self.P, self.q, A, b, self.cones, settings).solve()
        solver_time = time.perf_counter() - t0
        status = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate"}.get(str(sol.status), str(sol.status))
        if status not in ("optimal", "optimal_inaccurate"):
            return None, status, solver_time
        return self.unpack(np.array(sol.x)), status, solver_time

    def unpack(self, x: np.ndarray) -> dict:
        """The solution vector as the variables' arrays."""
        out = {}
        for name, spec in self.specs.items():
            seg = x[self.offsets[name]:self.offsets[name] + self.sizes[name]]
            out[name] = np.einsum("ijv,v->ij", Affine.variable(name, spec).coef[(None, name)], seg)
            if spec[0] == "scalar":
                out[name] = np.array(out[name][0, 0])
        return out
