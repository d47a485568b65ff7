"""A small LMI toolkit for CLARABEL, with a re-check that does not trust the solver.

An LMI system is written once, as a function ``build(v, p, ops)`` returning a list of
:class:`Lmi` (each a matrix that must be positive definite, semidefinite when
``strict=False``, or zero when ``equality``). The function is called

* with affine tracer objects (:mod:`uiofmu.conic`), once, to assemble CLARABEL's conic data
  (or with cvxpy variables and parameters, the straightforward formulation, ``backend="cvxpy"``),
* with the numpy arrays the solver returned (``ops = NUMPY_OPS``) to re-check every LMI by
  its eigenvalues, without the solver.

Strict inequalities are solved as ``F >= margin * I`` (:data:`~uiofmu.runtime.tolerances.LMI_MARGIN`,
100x the solver tolerance) and accepted by the re-check when ``eig_min(F) >=
VERIFY_FRACTION * margin``; equalities and non-strict LMIs are judged relative to the size of
the point (:data:`~uiofmu.runtime.tolerances.POINT_RTOL`), as the solver's tolerance is. A system whose
LMIs are homogeneous in the variables (all three families': only normalisations such as
``X >= I`` have a constant part) is repaired exactly when a point misses a normalisation by
round-off: the point is scaled up until it holds. A tunable is a parameter of the assembled
problem, so a search changes only its part of the data between solves.
"""

from __future__ import annotations

import time
import warnings
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from functools import partial
from types import SimpleNamespace
from typing import Callable

import numpy as np

from .runtime.errors import InfeasibleError
from .progress import progress
from .runtime.tolerances import (
    FIGURE_RTOL,
    FIRST_MARGIN_AGREEMENT,
    HELD_AGREEMENT,
    HELD_OPENING,
    HELD_PROBE,
    HELD_PROBES,
    LMI_MARGIN,
    MARGIN_DECISION_RTOL,
    MARGIN_SOLVER_TOL,
    POINT_RTOL,
    MARGIN_AGREEMENT,
    MARGIN_NEAR,
    MARGIN_PROBE,
    MARGIN_PROBES,
    SEARCH_MARGIN_CAP,
    SEARCH_MARGIN_FRACTION,
    SEARCH_RESOLUTION,
    SEARCH_TOL,
    SOLVER_TOL,
    VERIFY_FRACTION,
)
from .threads import blas_module


@dataclass(frozen=True)
class Lmi:
    """One linear matrix inequality ``matrix > 0`` (``>= 0`` when not strict), or a linear
    equality ``matrix = 0`` when ``equality`` is set."""

    name: str
    matrix: object
    strict: bool = True
    equality: bool = False


#: Solver statuses that prove infeasibility; any other failure is numerical.
INFEASIBLE = ("infeasible",)


class NumericalDesignError(InfeasibleError):
    """The solver failed numerically: no certificate was found, and none was proven impossible."""


def _np_sym(M):
    return 0.5 * (M + M.T)


def _cp_sym(M):
    return 0.5 * (M + M.T)


def _cvxpy():
    """cvxpy, imported on first use (reading problems and cards does not need it)."""
    return blas_module("cvxpy")


def _np_bmat(rows) -> np.ndarray:
    """A block matrix of 2-D blocks (np.block, np.vstack and np.hstack without their generality, which costs)."""
    return np.concatenate([np.concatenate([np.atleast_2d(np.asarray(b, dtype=float)) for b in row], axis=1)
                           for row in rows])


NUMPY_OPS = SimpleNamespace(bmat=_np_bmat, eye=np.eye, zeros=np.zeros, sym=_np_sym)


@dataclass(frozen=True)
class LmiSolution:
    """What a solve returned, and what the re-check found.

    Attributes
    ----------
    values : dict of str to numpy.ndarray
        The variables at the returned point.
    parameters : dict of str to float
        The parameter values solved for.
    status : str
        cvxpy's status string.
    eig_min : dict of str to float
        Smallest eigenvalue of every LMI, evaluated with numpy at ``values``.
    verified : bool
        True when every strict LMI has ``eig_min >= VERIFY_FRACTION * margin`` and every
        non-strict one ``eig_min >= -VERIFY_FRACTION * margin``.
    solve_time, setup_time : float
        CLARABEL's own time (direct backend: the wall time of its setup and solve calls; cvxpy
        backend: the solve time cvxpy reports) and the rest of the call, s.
    objective : float or None
    """

    values: dict
    parameters: dict
    status: str
    eig_min: dict
    verified: bool
    solve_time: float
    setup_time: float
    objective: float | None = None
    margin: float = LMI_MARGIN
    #: For a point of largest margin (:meth:`LmiSystem.largest_margin`): that margin, relative to the mean
    #: eigenvalue of the normalised matrices; None for the point of a plain solve.
    relative_margin: float | None = None
    #: Whether the point is a least objective at a held margin (:meth:`LmiSystem.least_at_margin`; then
    #: ``relative_margin`` is the margin held), and whether its figure was reproduced by a second solve.
    held: bool = False
    reproduced: bool = False
    #: For a point of largest margin refused because its probes (:data:`~uiofmu.runtime.tolerances.MARGIN_PROBES`:
    #: its rounding twin, a value :data:`~uiofmu.runtime.tolerances.MARGIN_PROBE` away) did not reproduce its margin
    #: (:func:`search`): its margin and a probe's, which the solver did not resolve.
    unresolved: tuple | None = None


def eig_min(lmis: list[Lmi]) -> dict:
    """Smallest eigenvalue of each (symmetrised) LMI matrix, with numpy; minus the largest
    absolute entry for an equality (so that 0 is perfect and negative is a violation).
    Matrices of one size are stacked and decomposed together."""
    out = {}
    groups: dict = {}
    for lmi in lmis:
        M = np.asarray(lmi.matrix, dtype=float)
        if lmi.equality:
            out[lmi.name] = -float(np.abs(M).max()) if M.size else 0.0
        else:
            groups.setdefault(M.shape, []).append((lmi.name, M))
    for items in groups.values():
        stack = np.array([m for _, m in items])
        low = np.linalg.eigvalsh(0.5 * (stack + np.swapaxes(stack, -1, -2)))[:, 0]
        out.update({name: float(v) for (name, _), v in zip(items, low)})
    return {lmi.name: out[lmi.name] for lmi in lmis}


def point_scale(values: dict) -> float:
    """``max(1, |x|_max)``: the size of a point, the largest entry of any of its variables."""
    return max([1.0] + [float(np.abs(np.asarray(v, dtype=float)).max()) for v in values.values()
                        if np.asarray(v).size])


def rejected(eigs: dict, lmis: list[Lmi], scale: float = 1.0, margin: float = LMI_MARGIN,
             verify_fraction: float = VERIFY_FRACTION, point_rtol: float = POINT_RTOL) -> dict:
    """The LMIs that fail the re-check rule, with the bound each one missed.

    A strict LMI needs ``eig_min >= verify_fraction * margin``; a non-strict LMI or an equality
    ``eig_min >= -max(verify_fraction * margin, point_rtol * scale)`` (for an equality
    ``eig_min`` is minus its largest residual), ``scale`` being :func:`point_scale`.

    Parameters
    ----------
    eigs : dict of str to float
        From :func:`eig_min`.
    lmis : list of Lmi
        The LMIs they belong to.
    scale : float
        The size of the point.
    margin, verify_fraction, point_rtol : float
        The rule's tolerances (:mod:`uiofmu.runtime.tolerances`).

    Returns
    -------
    dict of str to (float, float)
        ``name -> (eig_min, bound)`` of every LMI that fails.
    """
    loose = -max(verify_fraction * margin, point_rtol * scale)
    out = {}
    for l in lmis:
        bound = verify_fraction * margin if l.strict and not l.equality else loose
        if not eigs[l.name] >= bound:
            out[l.name] = (eigs[l.name], bound)
    return out


def accepted(eigs: dict, lmis: list[Lmi], margin: float = LMI_MARGIN,
             verify_fraction: float = VERIFY_FRACTION, scale: float = 1.0) -> bool:
    """True when every LMI passes the re-check rule of :func:`rejected` (the family then
    restores equalities exactly and re-checks the stored matrices)."""
    return not rejected(eigs, lmis, scale, margin, verify_fraction)


#: The margin variable of a largest-margin problem (a name no family uses).
MARGIN_VARIABLE = "largest margin t"

#: Weight of the system's own objective in its largest-margin problem: enough to pin variables that only
#: bound others (``t`` of ``X <= t I``, ``gamma``), far too little to move the margin.
MARGIN_TIE_BREAK = 1e-12

#: How the status of a point of :meth:`LmiSystem.least_at_margin` ends.
HELD = "(least objective at a held margin)"

#: How the status of a point of :meth:`LmiSystem.least_at_margin` ends when its figure was reproduced.
REPRODUCED = f"reproduced to {HELD_AGREEMENT:g}"


@dataclass
class LmiSystem:
    """An LMI problem, compiled once and solved for any parameter values.

    Parameters
    ----------
    name : str
        Shown in messages (e.g. ``"my-family decay"``).
    variables : dict
        ``name -> ("symmetric", n) | ("matrix", (rows, cols)) | ("scalar",)``, with how the variable maps
        back under a change of coordinates as an optional last element (:mod:`uiofmu.reductions`:
        ``symmetric(n)``, ``matrix(shape)``, ``scalar(role)``).
    parameters : dict
        ``name -> initial value`` of the scalar tunables (nonnegative).
    build : callable
        ``build(v, p, ops) -> list[Lmi]``, written with ``@``, ``.T``, ``*`` and ``ops``.
    objective : callable, optional
        ``objective(v)``: a scalar affine in the variables (e.g. ``v["t"]``) to minimise; feasibility when omitted.
    margin : float
        Strictness margin.
    solver_tol : float
        CLARABEL's feasibility and gap tolerances.
    backend : {"direct", "cvxpy"}
        ``direct`` (default) traces the LMIs once into CLARABEL's conic form
        (:mod:`uiofmu.conic`); ``cvxpy`` builds the same LMIs as a cvxpy problem (the
        straightforward formulation, kept for comparison and for the infeasibility diagnosis).
        Both are re-checked the same way.
    homogeneous : bool
        Every LMI is linear in the variables except non-strict normalisations ``F_lin(x) - c I``
        (``X >= I``): a point that misses a normalisation is then scaled by
        ``s = max c / eig_min(F_lin)`` (every other LMI scales with it) instead of rejected.
    certify : callable, optional
        ``certify(values, parameters) -> bool``: the family's checks at the matrices the runtime
        would store from a point the LMI re-check accepts. A point they reject counts as not
        verified, so a search goes on to a value that certifies instead of failing after it.
    recentre : callable, optional
        ``recentre(values) -> (system, back) | None``: the same LMIs in coordinates chosen from a
        point the solver returned but the re-check refused (e.g. a congruence that turns its Lyapunov
        matrix into the identity), as a system without ``recentre``, and ``back(values)``, its point
        in this system's variables. :meth:`solve` then solves once more there when the solver gave
        no proof of infeasibility, and re-checks the mapped point here, in these coordinates; when
        it verifies, later solves start in the new coordinates. Only a failed solve costs the extra
        solve. :meth:`uiofmu.reductions.Recentring.frame` is one.
    figure : callable, optional
        ``figure(values) -> float``: the figure a card reads off a point (its overshoot), which
        :meth:`least_at_margin` reproduces before it counts as the problem's; the objective without it.
    figure_spread : float
        Largest over smallest eigenvalue of the normalisations' constant (the plant's identity in these
        coordinates, :func:`uiofmu.scaling.plant_identity`; 1 for the identity): a normalisation met to the
        solver's tolerance relative to the point's size is met that much less accurately, relative, in its
        smallest direction, which the figure reads (:func:`accurate_optimum`).
    structure : optional
        Everything ``build`` and ``objective`` read besides the variables and the parameters (the family's
        matrices; see :func:`uiofmu.conic.fingerprint`). Systems of equal structure share one traced conic
        form (:func:`uiofmu.conic.traced`): the same LMIs at other parameter values, or the same design made
        again, are not traced again. None (the default): traced for this system alone.

    Attributes
    ----------
    assembly_time : float
        Seconds spent building the problem (tracing into conic form, or cvxpy's construction).
    solves : int
        Solves so far.
    solver_time : float
        CLARABEL's time summed over the solves, s (see :class:`LmiSolution`).
    """

    name: str
    variables: dict
    parameters: dict
    build: Callable
    objective: Callable | None = None
    margin: float = LMI_MARGIN
    solver_tol: float = SOLVER_TOL
    backend: str = "direct"
    homogeneous: bool = False
    certify: Callable | None = None
    recentre: Callable | None = None
    figure: Callable | None = None
    figure_spread: float = 1.0
    structure: object = None
    _conic: object = field(init=False, repr=False, default=None)
    _margin: tuple | None = field(init=False, repr=False, default=None)
    _held: dict = field(init=False, repr=False, default_factory=dict)
    _frame: tuple | None = field(init=False, repr=False, default=None)
    _vars: dict = field(init=False, repr=False)
    _params: dict = field(init=False, repr=False)
    _lmis: list = field(init=False, repr=False)
    _problem: object = field(init=False, repr=False)
    assembly_time: float = field(init=False, default=0.0)
    solves: int = field(init=False, default=0)
    solver_time: float = field(init=False, default=0.0)

    def __post_init__(self):
        if self.backend == "direct":        # imported here, before the clock: reading cards needs neither
            from .conic import ConicProblem, traced
        else:
            _cvxpy()
        self._problem = None
        t0 = time.perf_counter()
        if self.backend == "direct":
            self._conic = (ConicProblem if self.structure is None else partial(traced, self.structure))(
                self.variables, self.parameters, self.build, self.objective, self.margin)
        else:
            self._compile_cvxpy()
        self.assembly_time = time.perf_counter() - t0

    def _compile_cvxpy(self):
        cp = _cvxpy()
        ops = SimpleNamespace(bmat=cp.bmat, eye=np.eye, zeros=np.zeros, sym=_cp_sym)
        self._vars = {}
        for vname, spec in self.variables.items():
            if spec[0] == "symmetric":
                self._vars[vname] = cp.Variable((spec[1], spec[1]), symmetric=True, name=vname)
            elif spec[0] == "matrix":
                self._vars[vname] = cp.Variable(spec[1], name=vname)
            else:
                self._vars[vname] = cp.Variable(name=vname)
        self._params = {k: cp.Parameter(nonneg=True, value=float(v), name=k) for k, v in self.parameters.items()}
        self._lmis = self.build(self._vars, self._params, ops)
        constraints = []
        for lmi in self._lmis:
            M = lmi.matrix
            if lmi.equality:
                constraints.append(M == 0)
                continue
            shift = self.margin if lmi.strict else 0.0
            constraints.append(_cp_sym(M) - shift * np.eye(M.shape[0]) >> 0)
        goal = cp.Minimize(self.objective(self._vars)) if self.objective else cp.Minimize(0)
        self._problem = cp.Problem(goal, constraints)

    @property
    def recentred(self) -> bool:
        """Whether solves now start in coordinates chosen by ``recentre``."""
        return self._frame is not None

    def largest_margin(self, **parameters) -> LmiSolution:
        """The point of largest margin at the parameter values, scaled to the normalisations and re-checked.

        Solves the bounded problem of :meth:`uiofmu.conic.ConicProblem.margin_form` (derived once from
        the assembled LMIs): every strict LMI ``>= t I``, every normalisation ``X >= I`` as ``X >= t I``,
        the normalised matrices' traces adding up to 1, ``t`` maximised to
        :data:`~uiofmu.runtime.tolerances.MARGIN_SOLVER_TOL`. It is bounded and feasible at every
        parameter value (``t`` may be negative), and positive exactly where the system has a
        certificate. Its optimal value is determined by the problem to the solver's accuracy, where the
        point a feasibility solve stops at is not; its point, divided by ``t``, satisfies every
        normalisation with every strict LMI ``>= I``.

        With ``recentre``, a point of too small a margin is solved once more in the coordinates
        ``recentre`` chooses from it (as :meth:`solve` does), where the margin is measured; its point
        is mapped back and re-checked here.

        Returns
        -------
        LmiSolution
            Verified when the relative margin is at least
            :data:`~uiofmu.runtime.tolerances.MARGIN_DECISION_RTOL` and the scaled point passes
            :meth:`recheck` (the family's checks at the stored matrices included); ``relative_margin``
            holds the margin (None when CLARABEL returned no point).

        Raises
        ------
        ValueError
            When the system is not homogeneous, or has no normalisation.
        """
        if not self.homogeneous:
            raise ValueError(f"{self.name}: a largest margin needs a homogeneous system")
        return self._recentring(self._margin_in, parameters)

    def least_at_margin(self, held: float, **parameters) -> LmiSolution:
        """The least objective with the margin held at ``held``, re-checked.

        The problem of :meth:`largest_margin` with its normalisations' constants kept (``X >= I``), every
        strict LMI ``>= t I`` with ``t`` held at ``held`` times the mean eigenvalue of the normalised
        matrices (relative, as :attr:`LmiSolution.relative_margin`), and the system's own objective
        (the least overshoot) minimised: as well scaled as the largest margin, and its optimum, unlike the
        point a plain solve stops at next to the edge, is determined by the problem. A ``"max"`` search
        keeps this point at the value it found, with half the margin it decided that value by.

        Whether CLARABEL reached that optimum is not read off its word (``optimal`` or
        ``optimal_inaccurate`` moved with the BLAS kernel, on answers equal to 1e-5 and on answers 40 %
        apart alike, and either may come with no point): the problem is solved again with the margin held
        :data:`~uiofmu.runtime.tolerances.HELD_PROBE` higher, lower, twice that higher and lower
        (:data:`~uiofmu.runtime.tolerances.HELD_PROBES`), until the figures (:attr:`figure`, else the
        objective) of two solves agree to :data:`~uiofmu.runtime.tolerances.HELD_AGREEMENT`: the figure is then
        reproduced, and the earlier of the two points is kept. An answer CLARABEL did not converge to is one
        solve that agrees with no other (58.94 against 58.74 and 58.74). Where none of the first
        :data:`~uiofmu.runtime.tolerances.HELD_OPENING` solves gives a point that verifies, CLARABEL does not solve
        the held problem (InsufficientProgress, or answers the re-check refuses), and which of the later ones
        verify is the BLAS kernel's rounding: no more are made, and the figure is not the problem's. A margin
        held below :data:`~uiofmu.runtime.tolerances.MARGIN_DECISION_RTOL` is not solved for (its point
        would not verify).

        Returns
        -------
        LmiSolution
            ``held`` set and ``relative_margin`` the margin held; ``reproduced`` when the figure was reproduced
            (its ``status`` says both, for the card: :data:`HELD`, :data:`REPRODUCED`).
        """
        if not self.homogeneous:
            raise ValueError(f"{self.name}: a margin held needs a homogeneous system")
        if held < MARGIN_DECISION_RTOL:                 # its point would not verify (:meth:`_margin_in`): not solved
            pvals = self._parameter_values(parameters)
            return LmiSolution({}, pvals, f"not solved: margin {held:.3g} below {MARGIN_DECISION_RTOL:g} {HELD}", {},
                               verified=False, solve_time=0.0, setup_time=0.0, margin=self.margin,
                               relative_margin=held, held=True)
        first, found = None, []
        for i, k in enumerate((0, *HELD_PROBES)):
            if i == HELD_OPENING and not found:         # CLARABEL does not solve this problem: more solves are luck
                break
            sol = self._held_once(held * (1.0 + k * HELD_PROBE), parameters)
            first = first or sol
            if not sol.verified:                        # CLARABEL gave up on this one: the next probe
                continue
            figure = self._figure_of(sol)
            kept = next((s for f, s in found if reproduced(f, figure, HELD_AGREEMENT)), None)
            if kept is not None:                        # two solves agree: the earlier of them is kept
                return replace(kept, status=f"{kept.status}, {REPRODUCED}", reproduced=True)
            found.append((figure, sol))
        return found[0][1] if found else first

    def _parameter_values(self, parameters: dict) -> dict:
        """Every parameter's value as a float: ``parameters``' where given, the system's default otherwise."""
        return {k: float(parameters.get(k, v)) for k, v in self.parameters.items()}

    def _figure_of(self, sol: LmiSolution) -> float:
        """The figure :meth:`least_at_margin` compares: :attr:`figure` of the point, else its objective."""
        try:
            value = self.figure(sol.values) if self.figure is not None else sol.objective
        except (np.linalg.LinAlgError, ValueError):
            return float("nan")
        return float(value) if value is not None else float("nan")

    def _held_once(self, held: float, parameters: dict) -> LmiSolution:
        """One solve of :meth:`least_at_margin`: in the system's own coordinates first (the margin is
        relative to them), then as :meth:`_recentring` goes on."""
        attempt = lambda frame, pvals: self._margin_in(frame, pvals, held=held)   # noqa: E731
        if self._frame is not None:
            pvals = self._parameter_values(parameters)
            sol = attempt(None, pvals)
            if sol.verified:
                return sol
        return self._recentring(attempt, parameters)

    def _margin_form(self, held: float | None) -> tuple:
        """The largest-margin problem (or the least objective at the relative margin ``held``) and the total
        size of the normalised matrices, derived once from the assembled LMIs."""
        if self._margin is None or (held is not None and held not in self._held):
            from .conic import ConicProblem

            t0 = time.perf_counter()
            base = self._conic if self._conic is not None else ConicProblem(
                self.variables, self.parameters, self.build, self.objective, self.margin)
            if self._margin is None:
                self._margin = base.margin_form(MARGIN_VARIABLE, self.margin, MARGIN_TIE_BREAK)
            if held is not None:
                self._held[held] = base.margin_form(MARGIN_VARIABLE, self.margin, MARGIN_TIE_BREAK, held=held)
            self.assembly_time += time.perf_counter() - t0
        return self._margin if held is None else self._held[held]

    def _margin_in(self, frame, pvals: dict, held: float | None = None) -> LmiSolution:
        """The largest margin (or the least objective at the margin ``held``) in this system's coordinates
        (``frame`` None) or in a recentred ``frame`` ``(system, back)``: there the margin is the frame's,
        and its point is mapped back and re-checked here (see :meth:`largest_margin`)."""
        if frame is not None:
            system, back = frame
            inner = system.largest_margin(**pvals) if held is None else system.least_at_margin(held, **pvals)
            self.solves += 1
            self.solver_time += inner.solve_time
            if not inner.values:
                return replace(inner, verified=False)
            sol = self.recheck(back(inner.values), pvals, inner.status)
            return LmiSolution(sol.values, pvals, inner.status, sol.eig_min, sol.verified and inner.verified,
                               inner.solve_time, inner.setup_time, sol.objective, self.margin, inner.relative_margin,
                               inner.held)
        conic, size = self._margin_form(held)
        t0 = time.perf_counter()
        values, status, solve_time = (conic.solve(pvals, MARGIN_SOLVER_TOL) if held is None else
                                      conic.solve(pvals, self.solver_tol))
        total = time.perf_counter() - t0
        self.solves += 1
        self.solver_time += solve_time
        if not values:
            return LmiSolution({}, pvals, status, {}, False, solve_time, total - solve_time, None, self.margin)
        t = float(values.pop(MARGIN_VARIABLE))
        relative = t * size if held is None else held
        if not (t > 0 and np.isfinite(t)):
            return LmiSolution({}, pvals, status, {}, False, solve_time, total - solve_time, None, self.margin,
                               relative)
        scale = t if held is None else 1.0      # a held point keeps the normalisations' constants
        sol = self.recheck({k: np.asarray(v) / scale for k, v in values.items()}, pvals,
                           f"{status} {'(largest margin)' if held is None else HELD}")
        return LmiSolution(sol.values, pvals, sol.status, sol.eig_min,
                           sol.verified and relative >= MARGIN_DECISION_RTOL, solve_time,
                           max(total - solve_time, 0.0), sol.objective, self.margin, relative, held is not None)

    def decide(self, **parameters) -> LmiSolution:
        """Whether the parameter values have a certificate, decided by an optimal value.

        A homogeneous system on the direct backend is decided by :meth:`largest_margin`; any other
        by :meth:`solve` (the cvxpy backend keeps the straightforward formulation it is there to compare).
        """
        return self.largest_margin(**parameters) if self.decides_by_margin else self.solve(**parameters)

    @property
    def decides_by_margin(self) -> bool:
        """Whether :meth:`decide` uses :meth:`largest_margin` (a homogeneous system on the direct backend)."""
        return self.homogeneous and self.backend == "direct"

    def evaluate(self, values: dict, parameters: dict) -> list[Lmi]:
        """The LMIs as numpy matrices at ``values`` (the re-check's input)."""
        return self.build(values, parameters, NUMPY_OPS)

    def solve(self, **parameters) -> LmiSolution:
        """Solve for the given parameter values, then re-check the returned point.

        With ``recentre``, a point the re-check refuses (the solver proved nothing) is solved
        again in the coordinates ``recentre`` chooses from it (see :class:`LmiSystem`).

        Returns
        -------
        LmiSolution
            Also when the solver fails (``values`` empty, ``verified`` False).
        """
        return self._recentring(self._solve_in, parameters)

    def _recentring(self, attempt: Callable, parameters: dict) -> LmiSolution:
        """``attempt(frame, pvals)`` in the current coordinates, and once more in the coordinates
        ``recentre`` chooses from a refused point (the solver proved nothing); the new coordinates are kept
        when their point verifies."""
        pvals = self._parameter_values(parameters)
        sol = attempt(self._frame, pvals)
        if sol.verified or self.recentre is None or not sol.values or sol.status in INFEASIBLE:
            return sol
        try:
            t0 = time.perf_counter()
            frame = self.recentre(sol.values)
            self.assembly_time += time.perf_counter() - t0
        except (np.linalg.LinAlgError, ValueError):
            frame = None
        if frame is None:
            return sol
        again = attempt(frame, pvals)
        if again.verified:
            self._frame = frame
            return again
        return sol

    def _solve_in(self, frame, pvals: dict) -> LmiSolution:
        """One solve in this system's coordinates (``frame`` None) or in a recentred ``frame``
        ``(system, back)``, whose point is mapped back and re-checked here."""
        if frame is None:
            return self._solve_once(pvals)
        system, back = frame
        inner = system.solve(**pvals)
        self.solves += 1
        self.solver_time += inner.solve_time
        values = back(inner.values) if inner.values else {}
        sol = self.recheck(values, pvals, inner.status)
        return LmiSolution(sol.values, pvals, inner.status, sol.eig_min, sol.verified, inner.solve_time,
                           inner.setup_time, sol.objective, self.margin)

    def _solve_once(self, pvals: dict) -> LmiSolution:
        """One solve in this system's own coordinates, re-checked."""
        t0 = time.perf_counter()
        if self._conic is not None:
            values, status, solve_time = self._conic.solve(pvals, self.solver_tol)
            total = time.perf_counter() - t0
            return self._checked(values or {}, pvals, status, solve_time, total)
        cp = _cvxpy()
        for k, v in pvals.items():
            self._params[k].value = v
        try:
            with warnings.catch_warnings():   # inaccurate answers are judged by the re-check instead
                warnings.simplefilter("ignore", UserWarning)
                self._problem.solve(solver=cp.CLARABEL, tol_feas=self.solver_tol, tol_gap_abs=self.solver_tol,
                                    tol_gap_rel=self.solver_tol)
            status = self._problem.status
        except cp.error.SolverError as exc:
            status = f"solver_error: {exc}"
        total = time.perf_counter() - t0
        stats = self._problem.solver_stats
        solve_time = float(stats.solve_time) if stats and stats.solve_time is not None else total
        values = {}
        if all(v.value is not None for v in self._vars.values()) and status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            values = {k: np.array(v.value, dtype=float) for k, v in self._vars.items()}
        return self._checked(values, pvals, str(status), solve_time, total)

    def _checked(self, values: dict, pvals: dict, status: str, solve_time: float, total: float) -> LmiSolution:
        """The re-check of a returned point (the same for every backend); counts the solve."""
        self.solves += 1
        self.solver_time += solve_time
        sol = self.recheck(values, pvals, status)
        return LmiSolution(sol.values, pvals, status, sol.eig_min, sol.verified, solve_time,
                           max(total - solve_time, 0.0), sol.objective, self.margin)

    def recheck(self, values: dict, parameters: dict, status: str = "re-checked") -> LmiSolution:
        """Re-check a point at the given parameter values, without solving (see :func:`rejected`).

        A homogeneous system's point that misses a normalisation is scaled until it holds
        (the scaled point is returned).

        Parameters
        ----------
        values : dict of str to numpy.ndarray
            The variables (empty: nothing to check, not verified).
        parameters : dict of str to float
            The parameter values.
        status : str
            Recorded in the solution.

        Returns
        -------
        LmiSolution
        """
        pvals = self._parameter_values(parameters)
        eigs, ok, objective = {}, False, None
        if values:
            lmis = self.evaluate(values, pvals)
            eigs = eig_min(lmis)
            ok = accepted(eigs, lmis, self.margin, scale=point_scale(values))
            if not ok and self.homogeneous:
                values, lmis, eigs, ok = self._rescaled(values, pvals, lmis, eigs)
            if ok and self.certify is not None:
                try:
                    ok = bool(self.certify(values, pvals))
                except (np.linalg.LinAlgError, ValueError):
                    ok = False
            if ok and self.objective:
                objective = float(np.asarray(self.objective(values)))
        return LmiSolution(values, pvals, status, eigs, ok, 0.0, 0.0, objective, self.margin)

    def _rescaled(self, values, pvals, lmis, eigs):
        """The point scaled so that its normalisations hold (homogeneous systems)."""
        zero = {k: np.zeros_like(np.asarray(v, dtype=float)) for k, v in values.items()}
        need = 1.0
        for lmi, const in zip(lmis, self.evaluate(zero, pvals)):
            c = np.asarray(const.matrix, dtype=float)
            if lmi.strict or lmi.equality or not np.any(c):
                continue
            low = float(np.linalg.eigvalsh(0.5 * (c + c.T))[0])
            lin = np.asarray(lmi.matrix, dtype=float) - c
            lin_low = float(np.linalg.eigvalsh(0.5 * (lin + lin.T))[0])
            if low < 0 < lin_low:
                need = max(need, -low / lin_low)
        if need <= 1.0:
            return values, lmis, eigs, False
        scaled = {k: np.asarray(v, dtype=float) * (need * (1 + 1e-12)) for k, v in values.items()}
        lmis = self.evaluate(scaled, pvals)
        eigs = eig_min(lmis)
        return scaled, lmis, eigs, accepted(eigs, lmis, self.margin, scale=point_scale(scaled))

    def diagnose(self, **parameters) -> dict:
        """Which LMIs cannot hold: a phase-1 problem with one slack per strict LMI.

        Returns
        -------
        dict of str to float
            The slack each LMI needs (0 where it can hold), for the message of an
            infeasible design; empty when the phase-1 problem itself was not solved to
            optimality (its slacks would prove nothing).
        """
        cp = _cvxpy()
        if self._problem is None:
            self._compile_cvxpy()
        pvals = self._parameter_values(parameters)
        slack = {l.name: cp.Variable(nonneg=True, name=f"slack_{i}")
                 for i, l in enumerate(self._lmis) if not l.equality}
        cons = []
        for lmi in self._lmis:
            M = lmi.matrix
            if lmi.equality:
                cons.append(M == 0)
                continue
            size = M.shape[0]
            shift = self.margin if lmi.strict else 0.0
            cons.append(_cp_sym(M) + (slack[lmi.name] - shift) * np.eye(size) >> 0)
        for k, v in pvals.items():
            self._params[k].value = v
        prob = cp.Problem(cp.Minimize(sum(slack.values())), cons)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                prob.solve(solver=cp.CLARABEL)
        except cp.error.SolverError:
            return {}
        if prob.status != cp.OPTIMAL:
            return {}
        return {k: float(s.value) for k, s in slack.items() if s.value is not None}

    def require(self, **parameters) -> LmiSolution:
        """Solve and insist on a verified certificate.

        Raises
        ------
        InfeasibleError
            Naming the parameters, the solver status and the LMIs that cannot hold (or
            that failed the re-check, with their smallest eigenvalues).
        """
        sol = self.solve(**parameters)
        if sol.verified:
            return sol
        self.refuse(sol)

    def refuse(self, sol: LmiSolution, diagnose: bool = True):
        """Raise the :class:`InfeasibleError` that explains why ``sol`` is not a certificate.

        Parameters
        ----------
        sol : LmiSolution
            A solution that did not verify.
        diagnose : bool
            Name the LMIs that need slack (a phase-1 solve through cvxpy) when the solver
            returned no point.

        Raises
        ------
        InfeasibleError
            The LMIs the re-check rejects, with their values and bounds; or, when the solver
            returned no point, its status and the LMIs that need slack.
        """
        params = ", ".join(f"{k} = {v:.6g}" for k, v in sol.parameters.items())
        if sol.unresolved is not None:
            raise InfeasibleError(
                f"{self.name} LMIs at {params}: the largest margin did not come out again, within "
                f"{FIRST_MARGIN_AGREEMENT:g} of itself, with the variables in reversed order or at a value "
                f"{MARGIN_PROBE:g} away: "
                "the solver does not resolve these LMIs' margins, so no value of the range would be decided the same "
                "under every BLAS kernel; units that bring the states to comparable sizes, or a slower requirement, "
                "give margins it resolves")
        if sol.values:
            lmis = self.evaluate(sol.values, sol.parameters)
            bad = [f"{k}: eig_min = {v:.3g} < {b:.3g}"
                   for k, (v, b) in rejected(sol.eig_min, lmis, point_scale(sol.values), self.margin).items()]
            if not bad:
                raise InfeasibleError(f"{self.name} LMIs at {params}: CLARABEL answered {sol.status} and the LMIs "
                                      "hold, but the observer built from its point fails the checks at the stored "
                                      "matrices (its gains are too large for them in double precision)")
            raise InfeasibleError(f"{self.name} LMIs at {params}: CLARABEL answered {sol.status} but the re-check "
                                  f"rejects its point ({'; '.join(bad)})")
        need = {k: v for k, v in (self.diagnose(**sol.parameters) if diagnose else {}).items() if v > self.margin}
        which = "; ".join(f"{k} needs slack {v:.3g}" for k, v in sorted(need.items(), key=lambda kv: -kv[1]))
        if sol.status in INFEASIBLE:
            raise InfeasibleError(f"{self.name} LMIs are infeasible at {params} (CLARABEL: {sol.status})"
                                  + (f": {which}" if which else ""))
        raise NumericalDesignError(f"{self.name} LMIs at {params}: CLARABEL failed numerically ({sol.status}), "
                                   "which proves no infeasibility" + (f"; phase 1: {which}" if which else ""))


@dataclass(frozen=True)
class SearchResult:
    """The outcome of :func:`search`: the best verified value and its solution.

    ``solves`` counts the values the search decided (not the solves of the point kept at the end, which the
    system's ``solves`` include); ``bracket`` is the best value and the nearest refused one.
    """

    value: float
    solution: LmiSolution
    solves: int
    seconds: float
    bracket: tuple
    parameter: str = ""

    def to_data(self) -> dict:
        """What the card records about the search."""
        return {"parameter": self.parameter, "solves": self.solves, "seconds": self.seconds,
                "bracket": list(self.bracket)}


def search(system: LmiSystem, parameter: str, feasible_end: float, infeasible_end: float,
           tol: float = SEARCH_TOL, label: str | None = None, transform: Callable | None = None,
           name: str | None = None, safe_end: float | None = None, walk: int = 30,
           diagnose: bool = True) -> SearchResult:
    """Bisection for the best value of one tunable, keeping only re-checked certificates.

    ``infeasible_end`` is a value known (from theory) not to verify, or the limit of the range;
    the best value is the one closest to it that still verifies, within ``tol``. Each value is
    decided by :meth:`LmiSystem.decide`: for a homogeneous system, by the optimal value of its
    largest-margin problem (and the certificate of its point), so that the search ends at the same
    value under every BLAS kernel wherever the solver resolves that margin more finely than the
    search's step. When no value verifies that way, the search runs again deciding each value by a
    plain solve (the solver's point, re-checked): a certificate the margins miss is still found. The
    value found is then solved for the system's own objective (the least overshoot) with the margin held
    at half the search's threshold (:meth:`LmiSystem.least_at_margin`), whose point is kept when it
    certifies; otherwise the point of largest margin is. The threshold is the problem's own
    (:data:`~uiofmu.runtime.tolerances.SEARCH_MARGIN_FRACTION` of the margin at the first value that
    passed), and the bracket is narrowed only while the margins at its ends differ by more than
    :data:`~uiofmu.runtime.tolerances.SEARCH_RESOLUTION` thresholds: where the margin is flat near the
    edge, a finer end would be decided by the solver's last digits. The bracket
    comes from theory (zeros, fixed modes), and the search first tries the value ``tol`` inside
    it (never past ``feasible_end``): where theory's limit is reached (as for the building) that
    value is decided at once. Otherwise ``feasible_end`` is tried; when it does not verify either, values
    ever closer to ``safe_end`` (the end of the range where the design gets easiest, itself
    excluded: a decay of 1, an alpha of 0) are tried until one verifies, and bisection narrows
    the bracket from there. Every value returned lies strictly between the two ends of the range.

    Parameters
    ----------
    system : LmiSystem
        Compiled once; only the parameter changes between solves.
    parameter : str
        Name of the searched parameter (as in ``system.parameters``).
    feasible_end, infeasible_end : float
        The bracket.
    tol : float
        Stop when the bracket is narrower than this.
    label : str, optional
        Progress-bar label.
    transform : callable, optional
        Maps the searched value to the parameter value (e.g. ``lambda r: r * r``).
    name : str, optional
        The user's name of the searched value (``"decay"``), recorded in the result.
    safe_end : float, optional
        Where feasibility grows, beyond ``feasible_end``; without it a failing
        ``feasible_end`` ends the search.
    walk : int
        Most values tried between ``feasible_end`` and ``safe_end`` (each halves the distance).
    diagnose : bool
        Name the LMIs that need slack when nothing verifies (see :meth:`LmiSystem.refuse`).

    Returns
    -------
    SearchResult

    Raises
    ------
    InfeasibleError
        When no value tried verifies (with the diagnosis at the one closest to ``safe_end``).
    """
    f = transform or (lambda x: x)
    t0 = time.perf_counter()
    steps = max(0, int(np.ceil(np.log2(max(abs(feasible_end - infeasible_end), tol) / tol))))
    deciders = [system.decide] + ([system.solve] if system.decides_by_margin else [])
    solves = 0
    with progress(total=steps + 2, desc=label or f"search {parameter}", unit="solve") as bar:
        for decide in deciders:
            found = _bisect(decide, parameter, f, float(feasible_end), float(infeasible_end), tol, safe_end, walk,
                            bar)
            solves += found[3]
            if found[2].verified or found[2].unresolved:     # no plain solve decides what the margins cannot
                break
        good, bad, best, _, threshold = found
        if not best.verified:
            system.refuse(best, diagnose)
        best = _settled(system, parameter, f(good), best, threshold)
    return SearchResult(good, best, solves, time.perf_counter() - t0, (good, bad), name or parameter)


def reproduced(a: float, b: float, rtol: float) -> bool:
    """Whether a figure and its second solve agree: both finite, apart by at most ``rtol`` of the larger."""
    return bool(np.isfinite(a) and np.isfinite(b) and abs(a - b) <= rtol * max(abs(a), abs(b)))


def _passes(sol: LmiSolution, threshold: float) -> bool:
    """Whether a value passes: its point certifies, with a largest margin (where it has one) of at least
    ``threshold``."""
    return sol.verified and (sol.relative_margin is None or sol.relative_margin >= threshold)


def _decided(decide: Callable, parameter: str, value: float, twin: bool = False, away: int = 0) -> LmiSolution:
    """``decide`` at ``value`` moved by ``away`` times :data:`~uiofmu.runtime.tolerances.MARGIN_PROBE`, as its
    rounding twin (:func:`uiofmu.conic.rounding_twin`) with ``twin``."""
    from .conic import rounding_twin

    with rounding_twin() if twin else nullcontext():
        return decide(**{parameter: value * (1.0 + away * MARGIN_PROBE)})


def _judged(decide: Callable, parameter: str, value: float, threshold: float, first: bool = False) -> LmiSolution:
    """``decide`` at ``value`` (once more as its rounding twin, :func:`uiofmu.conic.rounding_twin`, when CLARABEL
    gave no answer); a largest margin within a factor :data:`~uiofmu.runtime.tolerances.MARGIN_NEAR` of
    ``threshold`` (any margin, with ``first``: the first value that passes sets the search's threshold) is decided
    again by the probes of :data:`~uiofmu.runtime.tolerances.MARGIN_PROBES` (:func:`_reproduced_near`,
    :func:`_reproduced_first`). A value they refuse keeps two of its margins as ``unresolved``: its margin is lost
    in the solver's rounding, which moves with the BLAS kernel."""
    sol = _decided(decide, parameter, value)
    if sol.relative_margin is None and sol.status.startswith("solver_error"):
        sol = _decided(decide, parameter, value, twin=True)
    t = sol.relative_margin
    if t is None or not sol.verified or not (first or threshold / MARGIN_NEAR <= t <= MARGIN_NEAR * threshold):
        return sol
    probe = partial(_decided, decide, parameter, value)
    return _reproduced_first(sol, probe) if first else _reproduced_near(sol, probe)


def _refused(sol: LmiSolution, again: LmiSolution) -> LmiSolution:
    """``sol`` refused, its margin and the margin of ``again`` (a probe of it) kept as ``unresolved``."""
    s = again.relative_margin
    return replace(sol, verified=False, unresolved=(sol.relative_margin, float("nan") if s is None else s))


def _reproduced_near(sol: LmiSolution, probe: Callable) -> LmiSolution:
    """A value near its search's threshold, probed in turn (``probe(twin, away)``, one of
    :data:`~uiofmu.runtime.tolerances.MARGIN_PROBES`) until two certified solves of it agree to
    :data:`~uiofmu.runtime.tolerances.MARGIN_AGREEMENT`: the earlier counts, with the smaller margin of the two
    solved in the problem's own order (a twin's margin vets, it does not count); refused when no two agree."""
    solved = [(sol, False)]
    for twin, away in MARGIN_PROBES:
        again = probe(twin, away)
        s = again.relative_margin
        pair = next(((e, e_twin) for e, e_twin in solved if e.verified and again.verified and s is not None
                     and reproduced(e.relative_margin, s, MARGIN_AGREEMENT)), None)
        if pair is not None:
            own = [e.relative_margin for e, is_twin in (pair, (again, twin)) if not is_twin]
            return replace(pair[0], relative_margin=min(own or [pair[0].relative_margin]))
        solved.append((again, twin))
    return _refused(sol, solved[1][0])


def _reproduced_first(sol: LmiSolution, probe: Callable) -> LmiSolution:
    """The first value that passes a search (it sets the threshold), probed by every one of
    :data:`~uiofmu.runtime.tolerances.MARGIN_PROBES`: it counts when each probe's margin agrees with its own to
    :data:`~uiofmu.runtime.tolerances.FIRST_MARGIN_AGREEMENT` (whether the probe's point certifies or not), or
    when both margins set the search's largest threshold (:func:`_capped`: the threshold is then the same
    whatever the digits), with the smallest margin solved in the problem's own order; refused at the first probe
    that does not agree."""
    own = [sol.relative_margin]
    for twin, away in MARGIN_PROBES:
        again = probe(twin, away)
        s = again.relative_margin
        if s is None or not (reproduced(sol.relative_margin, s, FIRST_MARGIN_AGREEMENT)
                             or _capped(sol.relative_margin) and _capped(s)):
            return _refused(sol, again)
        own += [] if twin else [s]
    return replace(sol, relative_margin=min(own))


def _capped(margin: float) -> bool:
    """Whether a first value's margin sets the search's largest threshold,
    :data:`~uiofmu.runtime.tolerances.SEARCH_MARGIN_CAP`."""
    return _threshold_at(margin) == SEARCH_MARGIN_CAP


def _threshold(first: LmiSolution) -> float:
    """A search's threshold from the first value that passed (see
    :data:`~uiofmu.runtime.tolerances.SEARCH_MARGIN_FRACTION`)."""
    return MARGIN_DECISION_RTOL if first.relative_margin is None else _threshold_at(first.relative_margin)


def _threshold_at(margin: float) -> float:
    """The threshold a first value's largest margin sets: :data:`~uiofmu.runtime.tolerances.SEARCH_MARGIN_FRACTION`
    of it, within :data:`~uiofmu.runtime.tolerances.MARGIN_DECISION_RTOL` and
    :data:`~uiofmu.runtime.tolerances.SEARCH_MARGIN_CAP`."""
    return min(max(SEARCH_MARGIN_FRACTION * margin, MARGIN_DECISION_RTOL), SEARCH_MARGIN_CAP)


def _resolved(good: LmiSolution, bad: LmiSolution, threshold: float) -> bool:
    """Whether the largest margins at a bracket's ends differ by less than the search resolves
    (:data:`~uiofmu.runtime.tolerances.SEARCH_RESOLUTION` thresholds). A margin closer to 0 than
    ``threshold / MARGIN_NEAR`` counts as 0: it is the solver's noise (the failing end of an ltv-auid search
    had 2.1e-10 under one BLAS kernel and 1.8e-9 under another, against a threshold of 1.4e-7, and that
    difference alone decided whether the search narrowed its bracket once more)."""
    if good.relative_margin is None or bad.relative_margin is None:
        return False
    settled = lambda t: 0.0 if abs(t) < threshold / MARGIN_NEAR else t      # noqa: E731
    return settled(good.relative_margin) - settled(bad.relative_margin) < SEARCH_RESOLUTION * threshold


def _bisect(decide: Callable, parameter: str, f: Callable, good: float, bad: float, tol: float,
            safe_end: float | None, walk: int, bar) -> tuple:
    """The bisection of :func:`search` with one way of deciding a value.

    Returns
    -------
    (float, float, LmiSolution, int, float)
        The best value and the nearest refused one, the solution at the best value (not verified
        when nothing verified: then the one closest to ``safe_end``, or the first whose margin the solver
        did not resolve, where the search stops), the solves made, and the threshold the margins were held
        to. A value that passes away from theory's limit sets the threshold, so it is decided twice
        (:func:`_judged` with ``first``).
    """
    step = min(tol, 0.5 * abs(good - bad))
    near = bad + (step if good > bad else -step)
    floor = SEARCH_RESOLUTION * MARGIN_DECISION_RTOL          # theory's limit, with a resolved margin
    best = _judged(decide, parameter, f(near), floor)
    bar.update()
    if _passes(best, floor):
        return near, bad, best, 1, _threshold(best)
    bad, refused, solves = near, best, 2
    best = _judged(decide, parameter, f(good), floor, first=True)
    bar.update()
    start = good
    for k in range(1, walk + 1 if safe_end is not None else 1):
        if best.verified or best.unresolved:
            break
        bad, refused = good, best
        good = start + (safe_end - start) * (1.0 - 0.5 ** k)
        best = _judged(decide, parameter, f(good), floor, first=True)
        solves += 1
        bar.update()
    if not best.verified:
        return good, bad, best, solves, MARGIN_DECISION_RTOL
    threshold = _threshold(best)
    while abs(good - bad) > tol and not _resolved(best, refused, threshold):
        mid = 0.5 * (good + bad)
        sol = _judged(decide, parameter, f(mid), threshold)
        solves += 1
        bar.update()
        if _passes(sol, threshold):
            good, best = mid, sol
        else:
            bad, refused = mid, sol
    return good, bad, best, solves, threshold


def accurate_optimum(solution: LmiSolution, spread: float = 1.0) -> bool:
    """Whether ``solution`` is the optimum of its system's own objective that CLARABEL reached to its full
    tolerance (``optimal``), with normalisations held to :data:`~uiofmu.runtime.tolerances.FIGURE_RTOL` (the
    solver's tolerance is relative to the point's size, and ``spread`` times less accurate in the
    normalisations' smallest direction: :attr:`LmiSystem.figure_spread`): a figure read off it is the problem's."""
    return (solution.status == "optimal" and solution.relative_margin is None
            and POINT_RTOL * point_scale(solution.values) * spread <= FIGURE_RTOL)


def held_margin(solution: LmiSolution, threshold: float | None = None) -> float | None:
    """The margin to hold a least-objective solve at (:meth:`LmiSystem.least_at_margin`) where ``solution``
    was decided by margins: half of ``threshold`` (a search's), or of the solution's own margin; the
    margin itself for a point already held; None for a point of a plain solve."""
    if solution.relative_margin is None:
        return None
    if solution.held:
        return solution.relative_margin
    return 0.5 * (threshold if threshold is not None else solution.relative_margin)


def _settled(system: LmiSystem, parameter: str, value: float, decided: LmiSolution,
             threshold: float) -> LmiSolution:
    """The point a search keeps at the value it found: the least objective at half the search's threshold
    (:meth:`LmiSystem.least_at_margin`, an optimum the problem determines) when that certifies, else the
    point of largest margin that decided the value. Its solves are the system's (the card's ``timing``),
    not the search's: those count the values decided, the same on every machine."""
    held = held_margin(decided, threshold)
    if held is None:
        return decided
    sol = system.least_at_margin(held, **{parameter: value})
    return sol if sol.verified else decided


@dataclass(frozen=True)
class Tuned:
    """A tunable's value and the verified solution that certifies it (see :func:`tune`)."""

    value: float
    solution: LmiSolution
    search: SearchResult | None
    reused: bool = False


def tune(system: LmiSystem, parameter: str, requested, *, feasible_end: float, infeasible_end: float,
         safe_end: float, tol: float = SEARCH_TOL, label: str | None = None, transform: Callable | None = None,
         name: str | None = None, diagnose: bool = True) -> Tuned:
    """A tunable that is a number or ``"max"``: solve at the number, or search for the best value.

    A number that does not verify directly is not refused yet: its point of largest margin may
    certify (a homogeneous system), and when the best value (searched then) lies on its far side,
    the best value's point certifies the number too, because the LMIs only get easier toward
    ``safe_end``; it is re-checked at the number and used. So a value on the feasible side of a
    certified ``"max"`` always designs.

    Parameters
    ----------
    system : LmiSystem
        The family's LMIs.
    parameter : str
        The system parameter the tunable sets.
    requested : float or "max"
        The user's value.
    feasible_end, infeasible_end, safe_end : float
        See :func:`search`.
    tol : float
        Search tolerance.
    label : str, optional
        Progress-bar label of a search.
    transform : callable, optional
        Maps the tunable to the parameter value.
    name : str, optional
        The tunable's name in the card.
    diagnose : bool
        Name the LMIs that need slack in the error (a phase-1 solve through cvxpy).

    Returns
    -------
    Tuned

    Raises
    ------
    InfeasibleError
        When no certificate is found (the message explains the requested value's failure).
    """
    f = transform or (lambda x: x)
    kwargs = dict(tol=tol, label=label, transform=transform, name=name, safe_end=safe_end, diagnose=diagnose)
    if requested == "max":
        found = search(system, parameter, feasible_end, infeasible_end, **kwargs)
        return Tuned(found.value, found.solution, found)
    value = float(requested)
    at = {parameter: f(value)}
    sol = system.solve(**at)
    if sol.verified and accurate_optimum(sol, system.figure_spread):
        return Tuned(value, sol, None)
    if system.decides_by_margin:
        decided = system.largest_margin(**at)
        if decided.verified:         # the least objective at half its margin: a figure the problem determines
            held = system.least_at_margin(held_margin(decided, min(decided.relative_margin, SEARCH_MARGIN_CAP)), **at)
            return Tuned(value, held if held.verified and held.reproduced else
                         sol if sol.verified else decided, None)
    if sol.verified:
        return Tuned(value, sol, None)
    try:
        found = search(system, parameter, feasible_end, infeasible_end, **kwargs)
    except InfeasibleError:
        system.refuse(sol, diagnose)
    if (value - found.value) * (safe_end - found.value) >= 0:
        reused = system.recheck(found.solution.values, {parameter: f(value)}, f"{found.solution.status} (reused)")
        if reused.verified:
            return Tuned(value, reused, None, reused=True)
    system.refuse(sol, diagnose)
