"""Direct conic assembly of LMI systems for CLARABEL, without cvxpy's canonicalisation.

An LMI system is written once as ``build(v, p, ops)`` (see :mod:`uiofmu.lmi`). Called with
:class:`Affine` variables and :class:`ParamAffine` parameters, the same function traces every
LMI as an affine map of the variables, with dense coefficient tensors per variable (the blocks
are small; there are many of them). :class:`ConicProblem` turns the traced LMIs into CLARABEL's
form ``A x + s = b``, ``s`` in zero and PSD-triangle cones, once, with one sparsity pattern
for every parameter value: a solve for new values forms ``A`` and ``b`` with one small matrix
product each and calls the solver. Systems of one structure (:func:`traced`: the same LMIs of the same data,
whatever their parameters' values) share one traced problem.
"""

from __future__ import annotations

import contextlib
import contextvars
import copy
import math
import threading
import time
from collections import OrderedDict
from functools import lru_cache
from types import SimpleNamespace

import clarabel
import numpy as np
import scipy.sparse as sp

SQRT2 = math.sqrt(2.0)

#: CLARABEL's statuses in cvxpy's words, as cvxpy's CLARABEL interface names them, so that both
#: backends of :class:`uiofmu.lmi.LmiSystem` report the same status. "Almost" answers are
#: cvxpy's ``*_inaccurate`` (not a proof); a status CLARABEL adds later is a ``solver_error``.
CLARABEL_STATUS = {
    "Solved": "optimal",
    "AlmostSolved": "optimal_inaccurate",
    "PrimalInfeasible": "infeasible",
    "AlmostPrimalInfeasible": "infeasible_inaccurate",
    "DualInfeasible": "unbounded",
    "AlmostDualInfeasible": "unbounded_inaccurate",
    "MaxIterations": "user_limit",
    "MaxTime": "user_limit",
    "NumericalError": "solver_error",
    "InsufficientProgress": "solver_error",
    "Unsolved": "solver_error",
}


#: Whether :meth:`ConicProblem.solve` hands CLARABEL its variables in reversed order (see :func:`rounding_twin`).
_REVERSED = contextvars.ContextVar("uiofmu_reversed_variables", default=False)


@contextlib.contextmanager
def rounding_twin():
    """Within this context, :meth:`ConicProblem.solve` solves its problem with the variables in reversed order
    (the columns of ``A`` and ``P`` and the entries of ``q`` reversed, the answer put back in order): the same
    problem, whose answer CLARABEL's sums round in another order, as another BLAS kernel's do. A decision read
    off a margin within that rounding agrees with its twin's on one machine only by chance; a solve at a value
    :data:`~uiofmu.runtime.tolerances.MARGIN_PROBE` away rounds in the same order and moves with it (see
    :func:`uiofmu.lmi._judged`). Solves in recentred coordinates, made within the context, are twins too."""
    token = _REVERSED.set(True)
    try:
        yield
    finally:
        _REVERSED.reset(token)


def cvxpy_status(clarabel_status) -> str:
    """CLARABEL's status in cvxpy's vocabulary (see :data:`CLARABEL_STATUS`).

    Parameters
    ----------
    clarabel_status : clarabel.SolverStatus or str
        The status of a CLARABEL solution.

    Returns
    -------
    str
        ``optimal``, ``optimal_inaccurate``, ``infeasible``, ``infeasible_inaccurate``,
        ``unbounded``, ``unbounded_inaccurate`` or ``user_limit``; a solver error is
        ``"solver_error: CLARABEL answered NAME"`` (as the cvxpy backend prefixes its
        ``SolverError``).
    """
    name = str(clarabel_status).removeprefix("SolverStatus.")
    status = CLARABEL_STATUS.get(name, "solver_error")
    return f"solver_error: CLARABEL answered {name}" if status == "solver_error" else status


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
    def constant(cls, value) -> "Affine":
        """A constant matrix (no variable)."""
        arr = np.array(value, dtype=float)
        return cls(arr.shape, {None: arr})

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
            other = Affine.constant(np.broadcast_to(np.asarray(other, dtype=float), self.shape))
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
def _cone_map(rows: int, cols: int, equality: bool):
    """Where each entry of an LMI matrix (row-major) goes in its cone: ``(row, weight, count)``.

    A PSD cone holds CLARABEL's scaled upper triangle of the symmetric part, column by
    column: entry ``F[i, j]`` adds ``-F[i, j] / 2`` to the row of the pair ``{i, j}``, times
    sqrt(2) off the diagonal (``-F[i, i]`` on it; the sign makes ``A x + s = b`` hold with
    ``s = F(x)``). A zero cone row is ``+F[i, j]`` itself. The arrays are shared (cached) and
    read-only."""
    if equality:
        row, weight, count = np.arange(rows * cols), np.ones(rows * cols), rows * cols
    else:
        if rows != cols:
            raise ValueError(f"an LMI matrix must be square, found {rows}x{cols}")
        i, j = np.divmod(np.arange(rows * rows), rows)
        lo, hi = np.minimum(i, j), np.maximum(i, j)
        row = hi * (hi + 1) // 2 + lo                   # upper triangle, column by column
        weight = np.where(i == j, -1.0, -0.5 * SQRT2)
        count = rows * (rows + 1) // 2
    row.flags.writeable = weight.flags.writeable = False
    return row, weight, count


class ConicProblem:
    """The traced LMIs of a system as CLARABEL data, assembled once.

    Every LMI is traced to its entries ``F(x) = F0 + sum_k p_k F_k + (linear in x)``; each entry
    goes to one row of its cone with one weight (:func:`_cone_map`), so the rows, columns and
    values of ``A`` and ``b`` for all LMIs and all parameters are computed at once from the
    stacked coefficients. ``A`` is kept as one sparsity pattern with a column of values per
    parameter: a solve forms its values with one small matrix product.

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
        self.specs = variables
        self._forms = {}                 # the forms margin_form derived, by their arguments
        self._layouts = {}               # what those forms share whatever the margin held (_margin_layout)
        self.offsets, self.sizes, self._basis = {}, {}, {}
        traced = {}
        total = 0
        for name, spec in variables.items():
            var = traced[name] = Affine.variable(name, spec)
            self._basis[name] = var.coef[(None, name)]
            self.offsets[name] = total
            self.sizes[name] = self._basis[name].shape[2]
            total += self.sizes[name]
        self.nvar = total
        self.keys = (None, *parameters)
        code = {k: i for i, k in enumerate(self.keys)}
        lmis = build(traced, {k: ParamAffine(0.0, {k: 1.0}) for k in parameters}, TRACE_OPS)

        maps, coef, const, diag = [], [], [], []
        self.cones = []
        self._kinds = []               # (first row, rows, size, kind) of every cone, for margin_form
        entry = row = 0
        for lmi in lmis:
            F = lmi.matrix if isinstance(lmi.matrix, Affine) else Affine.constant(lmi.matrix)
            m, n = F.shape
            rows, weights, count = _cone_map(m, n, lmi.equality)
            maps.append((rows + row, weights))
            if lmi.equality:
                self.cones.append(clarabel.ZeroConeT(count))
                self._kinds.append((row, count, m, "equality"))
            else:
                self.cones.append(clarabel.PSDTriangleConeT(m))
                normalisation = not lmi.strict and np.any(F.const.get(None, 0.0)) and \
                    all(k is None for k in F.const)
                self._kinds.append((row, count, m, "strict" if lmi.strict else
                                    "normalisation" if normalisation else "nonstrict"))
                if lmi.strict:                                    # F - margin I in the cone
                    diag.append(entry + np.arange(m) * (m + 1))
            for (key, var), T in F.coef.items():
                coef.append((code[key], entry, self.offsets[var], T.reshape(m * n, -1)))
            for key, c in F.const.items():
                const.append((code[key], entry, c.ravel()))
            entry += m * n
            row += count
        self.nrows = row
        to_row = np.concatenate([r for r, _ in maps] or [np.zeros(0, int)])
        to_weight = np.concatenate([w for _, w in maps] or [np.zeros(0)])
        self._pattern(coef, to_row, to_weight)
        c = np.zeros((entry, len(self.keys)))
        for k, first, vals in const:
            c[first:first + len(vals), k] += vals
        if diag:
            c[np.concatenate(diag), 0] -= margin
        self._b = np.zeros((row, len(self.keys)))
        np.add.at(self._b, to_row, -to_weight[:, None] * c)
        self.q = np.zeros(self.nvar)
        if objective is not None:
            for (key, var), T in objective(traced).coef.items():
                if key is not None:
                    raise TypeError(f"the objective must not depend on the parameter {key!r}")
                self.q[self.offsets[var]:self.offsets[var] + self.sizes[var]] += T[0, 0]
        self.P = sp.csc_matrix((np.zeros(0), np.zeros(0, int), np.zeros(self.nvar + 1, int)),
                               shape=(self.nvar, self.nvar))

    def margin_form(self, name: str, margin: float, tie_break: float,
                    held: float | None = None) -> tuple["ConicProblem", int]:
        """The largest-margin problem of these LMIs, from the assembled data (no second tracing), derived once
        for each set of arguments and kept (the systems that share this problem share its forms too).

        Every strict LMI ``F(x) - margin I`` becomes ``F(x) - t I``; every normalisation (a non-strict
        LMI with a constant, parameter-free part, such as ``X - I``) loses its constant and becomes
        ``F_lin(x) - t I``; one equality row makes the traces of the normalised ``F_lin`` add up to 1;
        the objective is ``-t`` plus ``tie_break`` times this problem's own. ``t`` is the variable
        ``name`` (a scalar, last).

        With ``held``, the least objective at a relative margin held: the normalisations keep their
        constants (``X >= I``), ``t`` is held at ``held`` times the mean eigenvalue of the normalised
        ``F_lin`` (the trace row becomes ``size t = held sum traces``), and the objective is this problem's
        own (the least overshoot, as a plain solve's, but with a margin relative to the point's own size).

        Returns
        -------
        (ConicProblem, int)
            The problem, and the total size of the normalised matrices.

        Raises
        ------
        ValueError
            When there is no normalisation (the margin would be unbounded).
        """
        key = (name, margin, tie_break, held)
        if key not in self._forms:
            self._forms[key] = self._margin_form(name, margin, tie_break, held)
        return self._forms[key]

    def _margin_form(self, name: str, margin: float, tie_break: float, held: float | None) -> tuple:
        """:meth:`margin_form`, derived afresh (:meth:`margin_form` keeps each form it derived); the forms at
        different ``held`` differ only in the trace row's values, so their layout (:meth:`_margin_layout`) is
        derived once."""
        key = (name, margin, tie_break, held is not None)
        if key not in self._layouts:
            self._layouts[key] = self._margin_layout(name, margin, tie_break, held is not None)
        out, size, trace_vals, tail, order = self._layouts[key]
        if held is not None:                                  # size t - held sum traces = 0
            trace_vals = -held * trace_vals
        out = copy.copy(out)
        out._forms, out._layouts = {}, {}
        out._values = np.vstack([self._values, trace_vals, *tail])[order]
        return out, size

    def _margin_layout(self, name: str, margin: float, tie_break: float, held: bool) -> tuple:
        """What a form of :meth:`margin_form` (``held``: one at a margin held) takes from this problem whatever the
        margin held: the form without its coefficients' values, the size of the normalised matrices, the trace
        row's values (minus the sum of the normalised matrices' diagonal rows), the rows after them, and the order
        of the coefficients."""
        def diagonal(first, m):
            j = np.arange(m)
            return first + j * (j + 1) // 2 + j

        strict = [diagonal(r, m) for r, _, m, kind in self._kinds if kind == "strict"]
        norms = [(r, c, m) for r, c, m, kind in self._kinds if kind == "normalisation"]
        if not norms:
            raise ValueError("a largest-margin problem needs a normalisation (a non-strict LMI with a constant part)")
        norm_diag = np.concatenate([diagonal(r, m) for r, _, m in norms])
        size = int(sum(m for *_, m in norms))
        t_rows = np.sort(np.concatenate(strict + ([] if held else [norm_diag])))
        keys = len(self.keys)
        cols = np.repeat(np.arange(self.nvar), np.diff(self._indptr))
        on_norm = np.zeros(self.nrows, dtype=bool)
        on_norm[norm_diag] = True
        on_trace = on_norm[self._indices]                     # the trace row: minus the sum of those rows
        trace_cols, where = np.unique(cols[on_trace], return_inverse=True)
        trace_vals = np.zeros((trace_cols.size, keys))
        np.add.at(trace_vals, where, -self._values[on_trace])
        t_vals = np.zeros((t_rows.size, keys))
        t_vals[:, 0] = 1.0                                    # s = F - t I
        trace_t = float(size) * np.eye(1, keys) if held else np.zeros((0, keys))
        rows = np.concatenate([self._indices, np.full(trace_cols.size + len(trace_t), self.nrows), t_rows])
        cols = np.concatenate([cols, trace_cols, np.full(len(trace_t), self.nvar), np.full(t_rows.size, self.nvar)])
        order = np.lexsort((rows, cols))
        out = copy.copy(self)
        out.nvar, out.nrows = self.nvar + 1, self.nrows + 1
        out._indices, out._values = rows[order], None
        out._indptr = np.searchsorted(cols[order], np.arange(out.nvar + 1))
        b = self._b.copy()
        for rows_ in strict:
            b[rows_, 0] += margin                             # the strictness margin is t now
        if not held:
            for r, c, _ in norms:
                b[r:r + c, 0] = 0.0                           # the normalisation's constant goes
        out._b = np.vstack([b, np.zeros((1, keys)) if held else np.eye(1, keys)])  # traces add up to 1
        out.cones = [*self.cones, clarabel.ZeroConeT(1)]
        out.q = np.concatenate([self.q, [0.0]]) if held else np.concatenate([tie_break * self.q, [-1.0]])
        out.P = sp.csc_matrix((np.zeros(0), np.zeros(0, int), np.zeros(out.nvar + 1, int)),
                              shape=(out.nvar, out.nvar))
        out.specs = {**self.specs, name: ("scalar",)}
        out.offsets, out.sizes = {**self.offsets, name: self.nvar}, {**self.sizes, name: 1}
        out._basis = {**self._basis, name: np.ones((1, 1, 1))}
        return out, size, trace_vals, (trace_t, t_vals), order

    def _pattern(self, blocks: list, to_row: np.ndarray, to_weight: np.ndarray):
        """``A``'s pattern (CSC) and its values per parameter key, from dense coefficient blocks
        ``(key, first entry, first column, block)``: the cone row, column and value of every
        coefficient are computed for all blocks at once, and coefficients landing on the same
        (row, column) are summed."""
        heads = np.array([(k, e, c, b.shape[1]) for k, e, c, b in blocks], dtype=int).reshape(-1, 4)
        keys, first_entry, first_col, widths = heads.T
        starts = np.cumsum([0] + [b.size for *_, b in blocks])
        vals = np.concatenate([b.ravel() for *_, b in blocks] or [np.zeros(0)])
        where = np.flatnonzero(vals)                   # only the nonzero coefficients get indices
        block = np.searchsorted(starts, where, side="right") - 1
        local = where - starts[block]
        entries = first_entry[block] + local // widths[block]
        rows, cols, keys = to_row[entries], first_col[block] + local % widths[block], keys[block]
        vals = vals[where] * to_weight[entries]
        order = np.lexsort((rows, cols))
        pairs = cols[order] * self.nrows + rows[order]
        first = np.ones(pairs.size, dtype=bool)
        first[1:] = pairs[1:] != pairs[:-1]
        slot = np.cumsum(first) - 1
        self._values = np.zeros((int(first.sum()), len(self.keys)))
        np.add.at(self._values, (slot, keys[order]), vals[order])
        self._indices = rows[order][first]
        self._indptr = np.searchsorted(cols[order][first], np.arange(self.nvar + 1))

    def data(self, params: dict):
        """CLARABEL's ``A`` (CSC) and ``b`` at the parameter values (one for every parameter)."""
        weights = np.array([1.0] + [float(params[k]) for k in self.keys[1:]])
        cached = getattr(self, "_csc_index", None)       # (a copy of a problem keeps its original's: checked)
        if cached is None or cached[0] is not self._indices or cached[1] is not self._indptr:
            # the index dtype scipy chooses (int32 where it holds them), converted once instead of at every solve
            fits = max(self.nrows, self.nvar, int(self._indptr[-1])) <= np.iinfo(np.int32).max
            cached = self._csc_index = (self._indices, self._indptr, *(
                (self._indices.astype(np.int32), self._indptr.astype(np.int32)) if fits else
                (self._indices, self._indptr)))
        A = sp.csc_matrix((self._values @ weights, *cached[2:]), shape=(self.nrows, self.nvar))
        return A, self._b @ weights

    def solve(self, params: dict, tol: float, reduced: float | None = None):
        """Solve for the parameter values; returns ``(values or None, status, solver_time)``.

        ``reduced``, when given, is the accuracy an ``optimal_inaccurate`` answer still has (CLARABEL's
        reduced gap and feasibility tolerances; its defaults are 5e-5 and 1e-4).
        ``solver_time`` is the wall time spent in CLARABEL's calls: its setup (presolve, KKT
        initialisation, equilibration) and its interior-point iterations. Within :func:`rounding_twin`
        the variables are handed to CLARABEL in reversed order."""
        A, b = self.data(params)
        P, q, reverse = self.P, self.q, _REVERSED.get()
        if reverse:
            A, P, q = A[:, ::-1].tocsc(), P[::-1, ::-1].tocsc(), q[::-1].copy()
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_feas = settings.tol_gap_abs = settings.tol_gap_rel = tol
        if reduced is not None:
            settings.reduced_tol_feas = settings.reduced_tol_gap_abs = settings.reduced_tol_gap_rel = reduced
        t0 = time.perf_counter()                      # CLARABEL's own time: its setup and its solve
        sol = clarabel.DefaultSolver(P, q, A, b, self.cones, settings).solve()
        solver_time = time.perf_counter() - t0
        status = cvxpy_status(sol.status)
        if status not in ("optimal", "optimal_inaccurate"):
            return None, status, solver_time
        x = np.array(sol.x)
        return self.unpack(x[::-1] if reverse else x), status, solver_time

    def unpack(self, x: np.ndarray) -> dict:
        """The solution vector as the variables' arrays."""
        out = {}
        for name, spec in self.specs.items():
            seg = x[self.offsets[name]:self.offsets[name] + self.sizes[name]]
            out[name] = self._basis[name] @ seg
            if spec[0] == "scalar":
                out[name] = np.array(out[name][0, 0])
        return out


#: Traced problems kept for systems of the same structure (:func:`traced`), the least recently used dropped first.
TRACED_KEPT = 32

_TRACED: OrderedDict = OrderedDict()
_TRACED_LOCK = threading.Lock()


def fingerprint(item):
    """A hashable stand-in for the data an LMI system's ``build`` reads, equal exactly when the data are.

    Arrays by dtype, shape and bytes (so ``-0.0`` and ``0.0`` differ, as they may in a product), numbers by type and
    ``repr``, strings and None as they are, tuples, lists and dicts of them recursively.

    Raises
    ------
    TypeError
        For anything else (its equality is not the data's).
    """
    if isinstance(item, (np.ndarray, np.generic)):
        arr = np.ascontiguousarray(item)
        return ("array", arr.dtype.str, arr.shape, arr.tobytes())
    if isinstance(item, (tuple, list)):
        return (type(item).__name__, *(fingerprint(x) for x in item))
    if isinstance(item, dict):
        return ("dict", *((fingerprint(k), fingerprint(v)) for k, v in item.items()))
    if item is None or isinstance(item, str):
        return item
    if isinstance(item, (bool, int, float, complex)):
        return (type(item).__name__, repr(item))
    raise TypeError(f"no fingerprint of a {type(item).__name__}")


def traced(structure, variables: dict, parameters: dict, build, objective, margin: float) -> ConicProblem:
    """The :class:`ConicProblem` of a system, traced once per structure.

    ``structure`` is everything ``build`` and ``objective`` read besides the variables and the parameters (the
    family's matrices, as :func:`fingerprint` takes them). The key adds the code of ``build`` and ``objective``, the
    variables' kinds and sizes, the parameters' names and the margin, so a system at other parameter values, or
    the same design made again, reuses the traced problem (and the largest-margin forms derived from it); the
    parameters' values are given per solve. The :data:`TRACED_KEPT` most recent are kept.
    """
    code = lambda f: None if f is None else (f.__code__, fingerprint(f.__defaults__))   # noqa: E731
    key = (fingerprint(structure), code(build), code(objective),
           tuple((name, spec[0], spec[1] if spec[0] != "scalar" else None) for name, spec in variables.items()),
           tuple(parameters), repr(float(margin)))
    with _TRACED_LOCK:
        problem = _TRACED.get(key)
        if problem is not None:
            _TRACED.move_to_end(key)
            return problem
    problem = ConicProblem(variables, parameters, build, objective, margin)
    with _TRACED_LOCK:
        _TRACED[key] = problem
        while len(_TRACED) > TRACED_KEPT:
            _TRACED.popitem(last=False)
    return problem
