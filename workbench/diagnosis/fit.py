"""One fitting engine for every effect: weighted nonlinear least squares with variable projection.

A :class:`Structure` is a parameterized model on top of a base model: its
nonlinear parameters ``theta`` (a delay, a frequency and damping, cutoffs) are
found by Levenberg-Marquardt least squares. On FRF data and on a periodic record's
excited lines (the problems whose ``domain`` is "frequency") :func:`levenberg_marquardt`
solves the small normal equations of the structure's analytic ``jacobian`` (FRF data: a
delay, lags, moved modes, and a joint refit of such parts, :meth:`Composite.jacobian`) or
of a finite-difference Jacobian (an added mode or term, whose linear parts are solved from
the misfit; the modal fit's dozens of parameters have their own ``normal_equations``);
on a simulated time record ``scipy.optimize.least_squares`` (trust-region reflective,
finite differences; :data:`FRF_SOLVER` selects it on the lines too, the reference of
``benchmarks/bench_speed.py --frf`` and of the tests), while the parameters that enter
linearly (mode residues, compliance and coupling matrices) are solved inside every residual
evaluation by the problem's closed-form linear fits (variable projection,
Golub & Pereyra 1973). Start points come from a coarse grid of ``theta``
evaluated by the same projected cost.

On FRF data a structure may offer ``lines(problem, base)`` (:func:`structure_lines`): the
same cost, residual norms and normal equations without building a model per evaluation
(a moved mode, a delay or a lag scales fixed terms by per-line factors:
:class:`~workbench.diagnosis.problem.LineTerms` compresses each line's residual to a
handful of numbers by a QR; an added mode or pseudo-mode is the base's misfit minus
the term). Screening and refinement evaluate those; the result is evaluated on the model.

Data flow::

    Structure.grid ──> cost on the grid ──> best starts ──> least_squares
         │                          (residual = problem.residual(Structure.build(theta)))
         └──────────── FitResult(model, theta ± std, linear parts ± std, cost, error)
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
import scipy.linalg
import scipy.linalg.blas
import scipy.optimize

from workbench.modal.model import ModalModel

__all__ = [
    "Structure",
    "Realized",
    "FitResult",
    "Screening",
    "fit",
    "fit_budget",
    "levenberg_marquardt",
    "parameter_std",
    "screen",
    "structure_lines",
]


@dataclass(frozen=True)
class Realized:
    """A structure evaluated at one theta: the model and the linear parameters it solved."""

    model: ModalModel
    linear: dict[str, Any] = field(default_factory=dict)
    linear_std: dict[str, Any] = field(default_factory=dict)


class Structure(Protocol):
    """A parameterized effect on top of a base model (see module docstring)."""

    effect: str
    theta_names: tuple[str, ...]

    def grid(self, problem, base: ModalModel) -> list[np.ndarray]:
        """Candidate start points, each of shape (n_theta,)."""

    def bounds(self, problem, base: ModalModel) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of theta."""

    def build(self, theta: np.ndarray, problem, base: ModalModel) -> Realized:
        """The augmented model at theta, its linear parts solved by projection."""

    def n_linear(self, base: ModalModel) -> int:
        """Number of linear parameters (for the information criterion)."""

    def report(self, fit_result: FitResult, problem, base: ModalModel) -> tuple[dict, dict]:
        """Physical parameters and their standard deviations, JSON-ready."""


@dataclass(frozen=True)
class FitResult:
    """Outcome of fitting one structure.

    Attributes
    ----------
    theta, theta_std : (n_theta,) arrays
        Nonlinear parameters and standard deviations (Jacobian, residual-scaled); NaN for a
        parameter the data do not determine (see :func:`parameter_std`).
    realized : Realized
        Model and linear parameters at ``theta``; linear standard deviations are
        scaled by ``sigma2``.
    cost : float
        Sum of squared weighted residuals.
    sigma2 : float
        Residual variance per observation, cost / (n_obs - n_params).
    n_params : int
    error : float
        The spec error measure of the fitted model.
    """

    structure: Any
    theta: np.ndarray
    theta_std: np.ndarray
    realized: Realized
    cost: float
    sigma2: float
    n_params: int
    error: float
    status: str = "ok"
    """"ok", or why the least-squares search stopped without converging."""

    @property
    def model(self) -> ModalModel:
        return self.realized.model

    @property
    def abandoned(self) -> bool:
        """Whether its search was given up far above a rival's cost (:func:`fit`'s ``bar``):
        ``theta`` is the best point it reached, ``theta_std`` NaN."""
        return self.status.startswith(ABANDONED)

    @property
    def effect(self) -> str:
        return self.structure.effect


#: Exceptions that mean "this parameter point is numerically infeasible" (a singular
#: projection, an overdamped or growing coupled mode, a floating-point trap, a Python float
#: overflow: a growing mode's ``|p| ** settle`` in a transient basis, an indepgen beam
#: suspension's coupled fit): such a grid point is scored as infinite cost and counted. Any
#: other exception (an InputError, a shape bug inside an effect's code) propagates: a broken
#: effect must fail loudly, not silently drop out of the ranking.
NUMERICAL_FAILURES = (np.linalg.LinAlgError, FloatingPointError, OverflowError)


@dataclass(frozen=True)
class Screening:
    """Grid screening of one structure.

    Attributes
    ----------
    cost : float
        Lowest projected cost on the grid (inf when every point failed numerically).
    starts : list of (n_theta,) arrays
        Grid points sorted by cost, best first (empty for a structure without parameters).
    n_failed : int
        Grid points scored as infinite because of a numerical failure.
    """

    cost: float
    starts: list
    n_failed: int = 0

    def __iter__(self):  # (cost, starts) unpacking, as callers used it
        return iter((self.cost, self.starts))


#: residual evaluations of one least-squares refinement, unless the structure asks for more
MAX_NFEV = 60


def fit_budget(structure) -> int:
    """Residual evaluations for refining ``structure`` from one start.

    :data:`MAX_NFEV`, or the structure's own ``max_nfev`` (a structure with many
    parameters and a finite-difference Jacobian needs more evaluations a step).
    """
    return int(getattr(structure, "max_nfev", MAX_NFEV))


#: relative finite-difference step of a Jacobian column (scipy's ``diff_step``)
DIFF_STEP = 1e-4

#: a search given a ``bar`` (:func:`fit`: the cost of a rival that leaves only the noise) is
#: given up where its best cost stays above HOPELESS_RATIO bars while it fell less than
#: HOPELESS_FALL-fold over its last HOPELESS_STEPS steps' evaluations (a step: n_theta + 1,
#: a Jacobian by differences and the trial point). Such a search can no longer matter: to
#: rank at all it would have to come down a hundredfold, to where the rival already
#: explains everything. Wrong structures grinding on a whole record cost most of a
#: diagnosis (an indep3 planar record without periods, crosstalk fitted to the floor in
#: 0.03 s: two suspensions then took 9 and 6 s at 2600x its cost, their best 1000x)
HOPELESS_RATIO = 100.0
HOPELESS_FALL = 2.0
HOPELESS_STEPS = 10
#: the status of a search given up (:attr:`FitResult.abandoned`)
ABANDONED = "abandoned"

#: how fit() refines a structure without analytic hooks on FRF data and on a periodic
#: record's lines: "lm" (Levenberg-Marquardt on the normal equations of a finite-difference
#: Jacobian, or of the structure's analytic ``jacobian``) or "trf" (scipy's trust-region
#: reflective with finite differences, which takes an SVD of the tall Jacobian every
#: iteration: the engine before, kept as the reference of benchmarks/bench_speed.py --frf
#: and of the tests' cross-checks)
FRF_SOLVER = "lm"

#: how fit() forms the Jacobian of scipy's trust-region search (a record simulated in the
#: time domain, a whole record's lines, a structure that asks for trf) for a structure with
#: ``secant = True``: "secant" (difference quotients at the start and after a rejected
#: step, Broyden's rank-one update after an accepted one: :class:`_SecantJacobian`) or
#: "2-point" (difference quotients at every accepted point, as every other structure).
#: Levenberg-Marquardt on normal equations (FRF data, a periodic record's lines) keeps
#: difference quotients: it rejects steps as it raises its damping, and secant updates
#: through those took more evaluations (indep3 beam time suspension's coupled fit: 119 ->
#: 173 evaluations and Jacobians 68 -> 99, no faster; without refreshing after a rejection
#: it ran out of its 400 evaluations above the optimum)
TIME_JACOBIAN = "secant"

#: fewest parameters whose search takes secant updates: with one or two a
#: difference-quotient Jacobian costs one or two evaluations, and the secant's less exact
#: steps took as many more (a moved mode, a 2-input actuator lag, a suspended rigid mode:
#: 34 -> 50, 102 -> 74, 51 -> 46 evaluations); with four lags 112 -> 44, 86 -> 64, a coupled
#: suspension's 17 parameters 669 -> 366. Only a structure started at an optimum asks
#: (``secant``: :class:`~workbench.diagnosis.effects.CoupledSuspension`, from its rigid
#: fit): from a grid start, where parameters are not yet identifiable (a rigid suspension's
#: P = I), the secant's trajectory stalled (indep3 beam time suspension: the rigid fit's
#: 60 evaluations ended at cost 44 where difference quotients reached 13.2 in 26; the
#: diagnosis then took three effects at 2.1x the floor instead of one at 1.0x)
SECANT_MIN_THETA = 3


class _Normal:
    """``normal(theta, r) -> (J^T J, J^T r)`` for :func:`levenberg_marquardt`, with its stops."""

    def __init__(self, fn, tolerances: dict):
        self.fn = fn
        self.tolerances = tolerances

    def __call__(self, theta, r):
        return self.fn(theta, r)


def _normal_equations(structure, problem, base, residual, lo, hi, lines=None) -> _Normal | None:
    """The normal equations fit() solves for ``structure``, or None for scipy's trf.

    A structure's ``normal_equations`` hook (analytic, the modal fit) comes first, with
    :func:`levenberg_marquardt`'s tight stops. On FRF data and a periodic record's lines
    (``problem.domain == "frequency"``, ``FRF_SOLVER == "lm"``) every other structure: the
    Jacobian of its compressed residual ``lines`` (:func:`structure_lines`; then
    ``residual`` evaluates it; differences of it where it has no Jacobian), else its
    ``jacobian`` hook (analytic; it
    returns None where it has none for the problem: the lines of a periodic record), else
    :func:`finite_difference_jacobian`, with scipy's default stops (1e-8: what the
    trust-region search used, and all a difference quotient resolves). On a record
    simulated in the time domain the same for a structure whose ``solver`` is "lm"
    (:class:`~workbench.diagnosis.effects.CoupledSuspension`). Elsewhere (any other
    structure on such a record, or the reference ``FRF_SOLVER == "trf"``): None.
    """
    if callable(getattr(structure, "normal_equations", None)):
        return _Normal(lambda th, r: structure.normal_equations(th, problem, base, r), {})
    solver = getattr(structure, "solver", None)
    if solver == "trf":
        return None  # the structure asks for scipy's trust region (see RigidSuspension)
    # on a record the structure chooses (CoupledSuspension asks for "lm"), on lines FRF_SOLVER
    on_record = getattr(problem, "domain", "time") != "frequency"
    if (solver if on_record else FRF_SOLVER) != "lm":
        return None
    jac = getattr(structure, "jacobian", None)

    def normal(theta, r):
        if lines is not None:  # its Jacobian, or differences of its residual
            J = lines.jacobian(theta) if lines.jacobian is not None else None
        else:
            J = jac(theta, problem, base) if callable(jac) else None
        if J is None:
            J = finite_difference_jacobian(residual, theta, r, lo, hi)
        return J.T @ J, J.T @ r

    return _Normal(normal, {"ftol": 1e-8, "xtol": 1e-8, "gtol": 1e-8})


def structure_lines(structure, problem, base):
    """The structure's residual compressed per line on FRF data, or None.

    A structure whose parameters reach an FRF's prediction only through per-line factors
    of fixed terms (a moved mode, a delay, a lag) offers ``lines(problem, base)``: an
    object with ``residual(theta)`` and ``jacobian(theta)`` whose norms and inner products
    are those of ``problem.residual(structure.build(theta, ...).model)`` and of its
    derivative (:class:`~workbench.diagnosis.problem.LineTerms`), at a fraction of the
    cost and without building a model. :func:`screen` and :func:`fit` evaluate those.
    """
    fn = getattr(structure, "lines", None)
    if not callable(fn):
        return None
    # kept on the problem for its base: a screening, the grid it screens and the fit from
    # it ask for the same structure on the same base (each a QR per line)
    cache = getattr(problem, "lines_cache", None)
    if cache is None:
        return fn(problem, base)
    key = (id(structure), id(base))
    hit = cache.get(key)
    if hit is not None and hit[0] is structure and hit[1] is base:
        return hit[2]
    if len(cache) >= 32:
        cache.clear()
    cache[key] = (structure, base, fn(problem, base))
    return cache[key][2]


class _SecantJacobian:
    """The Jacobian of scipy's trust-region search by Broyden's secant updates (Broyden 1965).

    ``fun`` evaluates the residual and keeps it; ``jac(x)`` (trf asks for it at every
    accepted point, where ``fun`` was just evaluated) is :func:`finite_difference_jacobian`
    at the start, after a step the trust region rejected (the model of the residual was
    wrong there: more than one evaluation since the last Jacobian), and after
    :attr:`MAX_UPDATES` updates in a row; else the last Jacobian with the rank-one update
    ``J + (dr - J dx) dx^T / dx^T dx`` of the accepted step, which makes it exact along
    that step at no evaluation (a difference-quotient Jacobian costs ``n_theta`` residual
    evaluations, most of a search's time on a simulated record: a coupled suspension's 17
    parameters). ``fresh`` says whether the last one was difference quotients.
    """

    #: secant updates in a row before difference quotients again
    MAX_UPDATES = 4

    def __init__(self, residual, lo, hi):
        self.residual = residual
        self.lo, self.hi = lo, hi
        self.x = self.r = None  # the last evaluated point and its residual
        self.J = self.xJ = self.rJ = None  # the last Jacobian, its point and residual
        self.calls = 0  # evaluations since the last Jacobian
        self.updates = 0  # secant updates in a row
        self.fresh = False

    def fun(self, x):
        if self.x is not None and np.array_equal(self.x, x):
            return self.r  # a search taken up from its end (:func:`_trust_region`)
        r = self.residual(x)
        self.x, self.r = np.array(x, float), r
        self.calls += 1
        return r

    def prime(self, x, r, J):
        """Difference quotients ``J`` at ``x`` (residual ``r``), where a search goes on."""
        self.x = self.xJ = np.array(x, float)
        self.r = self.rJ = r
        self.J, self.calls, self.updates, self.fresh = J, 0, 0, True

    def __call__(self, x):
        x = np.array(x, float)
        if self.fresh and self.calls == 0 and np.array_equal(self.xJ, x):
            return self.J
        if self.x is not None and np.array_equal(self.x, x):
            r = self.r
        else:
            r = self.residual(x)
        dx = None if self.xJ is None else x - self.xJ
        if (
            self.J is None
            or self.calls > 1
            or self.updates >= self.MAX_UPDATES
            or not np.any(dx)
            or not np.all(np.isfinite(r))
        ):
            J = finite_difference_jacobian(self.residual, x, r, self.lo, self.hi)
            self.updates, self.fresh = 0, True
        else:
            u, v = (r - self.rJ) - self.J @ dx, dx / (dx @ dx)
            if self.J.flags.f_contiguous and self.J.dtype == np.float64:
                # in place (BLAS dger): a tall J's outer product allocated and summed cost
                # 10x more (50 000 x 37: 8 ms)
                J = scipy.linalg.blas.dger(1.0, u, v, a=self.J, overwrite_a=True)
            else:
                J = self.J + np.outer(u, v)
            self.updates, self.fresh = self.updates + 1, False
        self.J, self.xJ, self.rJ, self.calls = J, x, r, 0
        return J


def finite_difference_jacobian(residual, x, r, lo, hi, *, rel_step: float = DIFF_STEP):
    """Forward-difference Jacobian (n_obs, n_x) of ``residual`` at ``x``, where it is ``r``.

    The step is scipy's ``2-point`` rule, ``rel_step sign(x) max(1, |x|)`` (sign(0) = 1),
    taken backwards where the forward point leaves the bounds ``lo``, ``hi``.
    """
    x = np.asarray(x, float)
    h = rel_step * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    out = (x + h < lo) | (x + h > hi)
    h = np.where(out & (x - h >= lo) & (x - h <= hi), -h, h)
    J = np.empty((x.size, np.size(r)))  # filled by rows: a column of a C-order J is strided
    for i in range(x.size):
        xi = x.copy()
        xi[i] += h[i]
        J[i] = (residual(xi) - r) / (xi[i] - x[i])
    return J.T


def screen(structure: Structure, problem, base: ModalModel) -> Screening:
    """Projected cost on the structure's grid, grid points sorted by cost, numerical failures.

    A structure without nonlinear parameters is evaluated once (its fit is exact). A
    structure with lines on the problem (:func:`structure_lines`: FRF data, its residual
    compressed line by line) is evaluated on them, no model built; else a problem
    with a ``costs(models)`` method (a periodic record's lines:
    :meth:`~workbench.diagnosis.problem.PeriodicProblem.costs`) evaluates the grid's models
    together, the same costs as one by one; elsewhere each point is built and evaluated in turn.
    """
    lo, hi = (np.asarray(b, float) for b in structure.bounds(problem, base))
    if lo.size == 0:
        return Screening(problem.cost(structure.build(np.zeros(0), problem, base).model), [])
    grid = [np.clip(np.asarray(g, float), lo, hi) for g in structure.grid(problem, base)]
    lines = structure_lines(structure, problem, base) if grid else None

    def cost(g):
        if lines is not None:
            return lines.cost(g)
        return problem.cost(structure.build(g, problem, base).model)

    costs = []
    if lines is None and callable(getattr(problem, "costs", None)):
        # a problem that evaluates a grid's models together (a periodic record's lines:
        # PeriodicProblem.costs), the same costs; built and evaluated in its batches
        # (``batch``): what a build computes and the problem keeps for a few dozen models (an
        # added mode's transient basis, a whole record's 16 000 rows) is still there when
        # the model is evaluated, where a whole grid built first had pushed it out
        step = max(int(getattr(problem, "batch", 0) or len(grid)), 1)
        for start in range(0, len(grid), step):
            models = []
            for g in grid[start : start + step]:
                try:
                    models.append(structure.build(g, problem, base).model)
                except NUMERICAL_FAILURES:
                    models.append(None)
            costs.extend(problem.costs(models))
    else:
        for g in grid:
            try:
                costs.append(cost(g))
            except NUMERICAL_FAILURES:
                costs.append(np.inf)
    costs = np.asarray(costs, float)
    costs[~np.isfinite(costs)] = np.inf  # a NaN cost is a numerical failure too
    order = np.argsort(costs, kind="stable")
    n_failed = int(np.sum(np.isinf(costs)))
    return Screening(float(costs[order[0]]), [grid[i] for i in order], n_failed)


def fit(
    structure: Structure,
    problem,
    base: ModalModel,
    *,
    starts: list[np.ndarray] | None = None,
    n_starts: int = 2,
    max_nfev: int = MAX_NFEV,
    bar: float | None = None,
) -> FitResult:
    """Fit ``structure`` on top of ``base`` to the data of ``problem``.

    Parameters
    ----------
    structure : Structure
    problem : FrfProblem or TimeProblem
    base : ModalModel
        The model to augment (the nominal, or the nominal with earlier findings), in the
        diagnosis's form (:func:`workbench.diagnosis.modal.decompose`).
    starts : list of (n_theta,) arrays, optional
        Start points sorted best first (from :func:`screen`); by default the grid is screened here.
    n_starts : int
        Number of distinct start points refined by least squares.
    max_nfev : int
        Residual evaluations per refinement.
    bar : float, optional
        The cost (sum of squared weighted residuals) of a rival that already leaves only
        the noise: a search that stalls far above it is given up (:data:`HOPELESS_RATIO`),
        the result :attr:`~FitResult.abandoned`, at the best point it reached.
    """

    infeasible: list[float] = []
    # what the search evaluates: the model's residual, or the structure's lines (below)
    evaluate = [lambda th: problem.residual(structure.build(th, problem, base).model)]
    size = [problem.n_obs]

    basin: list = [None]  # the first search's optimum, once there is one (_Basin)
    progress: list = [None]  # the current search's, where there is a bar (_Progress)

    def residual(theta):
        try:
            r = evaluate[0](theta)
            size[0] = r.size
            if basin[0] is not None:
                basin[0].check(theta, r)
            if progress[0] is not None:
                progress[0].check(theta, r)
            return r
        except NUMERICAL_FAILURES:
            # a trial point the structure cannot realize (an overdamped coupled mode): a
            # residual far above the start's, so the trust region rejects the step and shrinks
            # (the model's residual and a structure's lines share its norm, see
            # structure_lines; a compressed one is not size n_obs: the fill takes its size)
            if not infeasible:
                r0 = problem.residual(base)
                infeasible.append(1e3 * max(np.sqrt(np.mean(r0**2)), 1e-150))
            return np.full(size[0], infeasible[0])

    lo, hi = (np.asarray(b, float) for b in structure.bounds(problem, base))
    n_theta = lo.size
    status = "ok"
    if n_theta == 0:
        theta, jac, gram = np.zeros(0), np.zeros((problem.n_obs, 0)), None
    else:
        if starts is None:
            _, starts = screen(structure, problem, base)
        starts = _distinct(starts, n_starts, hi - lo)
        best = None
        # a start on a bound (a zero delay, say) stalls the trust region: the first steps are
        # tiny relative to |x| = 0 and xtol ends the search; start just inside
        inner = np.where(np.isfinite(hi - lo), 1e-3 * (hi - lo), 0.0)
        # optional hooks (workbench.modal.fit.ModalStructure): normal_equations(theta, problem,
        # base, r) -> (J^T J, J^T r), or jacobian(theta, problem, base) -> J, analytic; they run
        # Levenberg-Marquardt on the normal equations. On FRF data every other structure runs
        # it too, on finite differences (a jacobian hook may return None: none for this
        # problem); elsewhere finite differences in scipy's trust-region reflective. The LM
        # path evaluates a structure's compressed residual where it has one (the reference
        # FRF_SOLVER == "trf" keeps the model's residual)
        lines = structure_lines(structure, problem, base) if FRF_SOLVER == "lm" else None
        if lines is not None and lines.residual is None:
            lines = None  # a cheap cost only: the model's residual is searched
        normal = _normal_equations(structure, problem, base, residual, lo, hi, lines)
        if lines is not None and (normal is not None or problem.domain == "time"):
            # the same norms and inner products as the model's residual (structure_lines);
            # in the time domain the residual itself (an added term's, on a record from rest)
            evaluate[0] = lines.residual
        coords = _Coordinates.of(structure, problem, base, lo, hi)
        jac = None if normal is not None else _trust_region_jacobian(structure, problem, base)
        for th0 in starts:
            th0 = np.clip(th0, lo + inner, hi - inner)
            if bar is not None:
                progress[0] = _Progress(bar, n_theta)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                try:
                    res = coords.search(residual, normal, th0, max_nfev, structure, jac)
                except _SameBasin:
                    continue
                except _Hopeless as stop:
                    res = stop.result
            if best is None or res.cost < best.cost:
                best = res
                basin[0] = _Basin.of(best, lo.size, problem.n_obs)
        theta, jac, gram = best.x, best.get("jac"), best.get("gram")
        if not best.success:
            status = (
                best.message
                if str(best.message).startswith(ABANDONED)
                else f"least squares stopped: {best.message}"
            )
        theta = _over_kinks(structure, problem, base, theta)
    realized = structure.build(theta, problem, base)
    r = problem.residual(realized.model)
    cost = float(r @ r)
    n_params = n_theta + structure.n_linear(base)
    sigma2 = cost / max(problem.n_obs - n_params, 1)
    if status != "ok" and _settled(best, lo, hi, sigma2):
        status = "ok"
    if n_theta and jac is None and gram is None:  # a search given up: no Jacobian at its end
        theta_std = np.full(n_theta, np.nan)
    else:
        theta_std = parameter_std(jac, sigma2, gram=gram) if n_theta else np.zeros(0)
    lin_std = {k: np.asarray(v) * np.sqrt(sigma2) for k, v in realized.linear_std.items()}
    realized = Realized(realized.model, realized.linear, lin_std)
    return FitResult(
        structure=structure,
        theta=np.asarray(theta, float),
        theta_std=theta_std,
        realized=realized,
        cost=cost,
        sigma2=sigma2,
        n_params=n_params,
        error=problem.error(realized.model),
        status=status,
    )


def _over_kinks(structure, problem, base, theta) -> np.ndarray:
    """``theta``, or the point of the structure's ``kinks`` hook (points near ``theta`` where
    its cost is not differentiable) that explains the whole record better.

    A minimum on a kink is where a least-squares search cannot land: it differences one
    side's slope and steps past it. A delay of exactly one sample (the ZOH response bends
    there; a computation delay is often whole samples) on an indepgen closed-loop stage
    record: the steady-state lines, which hardly tell 1 % of a sample, fitted it 1.2 %
    long, whose from-rest simulation left 1.15x the floor (1.00x on the sample), and a
    pseudo-mode was added to make up the difference. Judged on the whole record
    (``record_cost``: the spec's error, the record's start included)."""
    fn = getattr(structure, "kinks", None)
    if fn is None:
        return theta
    points = fn(theta, problem, base)
    if not points:
        return theta
    best = problem.record_cost(structure.build(theta, problem, base).model)
    for k in points:
        c = problem.record_cost(structure.build(k, problem, base).model)
        if c < best:
            theta, best = np.asarray(k, float), c
    return theta


#: a search stopped by its budget whose Gauss-Newton step from its end would lower the cost
#: by at most this many noise variances ends at its optimum to within the noise (in the
#: metric of the parameters' covariance, the step is at most half a standard deviation):
#: converged. A joint refit crawling along a weakly determined direction (a pseudo-mode's
#: frequency far above the band) spends its budget on fractions of a noise variance
SETTLED_GAIN = 0.25


def _settled(res, lo: np.ndarray, hi: np.ndarray, sigma2: float) -> bool:
    """Whether the search result ``res`` (stopped without meeting its stops) lies at its
    optimum to within the noise: the Gauss-Newton step from its end, over the parameters
    that no bound holds (a parameter on its bound with the gradient pushing outwards is
    held), would lower the cost ``|r|^2`` by at most :data:`SETTLED_GAIN` ``sigma2``.

    From the result's normal equations (``gram``, ``grad``: Levenberg-Marquardt) or its
    Jacobian (``jac``, ``fun``: scipy's trust region); False without them.
    """
    x = np.asarray(res.x, float)
    H, g = res.get("gram"), res.get("grad")
    if H is None or g is None:
        J, r = res.get("jac"), res.get("fun")
        if J is None or r is None or np.shape(J) != (np.size(r), x.size):
            return False
        J = np.asarray(J, float)
        H, g = J.T @ J, J.T @ np.asarray(r, float)
    H, g = np.asarray(H, float), np.asarray(g, float)
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(g)) and np.isfinite(sigma2)):
        return False
    free = ~_held(x, g, lo, hi, 1e-9 * np.where(np.isfinite(hi - lo), hi - lo, 1.0))
    if not np.any(free):
        return True
    Hf, gf = H[np.ix_(free, free)], g[free]
    dx = np.linalg.lstsq(Hf, -gf, rcond=1e-12)[0]
    return float(-gf @ dx) <= SETTLED_GAIN * sigma2


def _held(x: np.ndarray, g: np.ndarray, lo, hi, tol=0.0) -> np.ndarray:
    """The parameters a bound holds (the active set): on ``lo`` or ``hi`` (within ``tol``)
    with the gradient ``g`` of the cost pushing them outwards."""
    return ((x <= lo + tol) & (g > 0)) | ((x >= hi - tol) & (g < 0))


def _trust_region_jacobian(structure, problem, base):
    """``jac(theta) -> J`` (n_obs, n_theta) for scipy's trust region from the structure's
    analytic ``jacobian`` hook on FRF data (a structure that asks for trf there: a
    suspension's turned modes), or None (difference quotients). A point where the hook
    has none or the model cannot be built falls back to difference quotients of the
    residual the search evaluates."""
    hook = getattr(structure, "jacobian", None)
    if getattr(problem, "kind", "") != "frf" or not callable(hook):
        return None

    def jac(theta, residual, r, lo, hi):
        try:
            J = hook(theta, problem, base)
        except NUMERICAL_FAILURES:
            J = None
        if J is None or not np.all(np.isfinite(J)):
            return finite_difference_jacobian(residual, theta, r, lo, hi)
        return J

    return jac


class _SameBasin(Exception):
    """A later start's search reached the first search's optimum (:class:`_Basin`)."""


class _Hopeless(Exception):
    """A search given up (:class:`_Progress`); ``result`` its best point as scipy's
    OptimizeResult (``x``, ``fun``, ``cost`` as scipy's half sum of squares)."""

    def __init__(self, result: scipy.optimize.OptimizeResult):
        super().__init__(result.message)
        self.result = result


class _Progress:
    """A search's best cost, evaluation by evaluation, against a ``bar`` (:func:`fit`):
    :meth:`check` raises :class:`_Hopeless` where the search stalls far above it
    (:data:`HOPELESS_RATIO`)."""

    def __init__(self, bar: float, n_theta: int):
        self.limit = HOPELESS_RATIO * bar
        self.window = HOPELESS_STEPS * (n_theta + 1)
        self.best, self.x, self.r = np.inf, None, None
        self.path: list[float] = []  # the best cost after each evaluation

    def check(self, theta, r) -> None:
        c = float(r @ r)
        if c < self.best:
            self.best, self.x, self.r = c, np.array(theta, float), r
        self.path.append(self.best)
        if (
            len(self.path) > self.window
            and self.best > self.limit
            and self.path[-1 - self.window] < HOPELESS_FALL * self.best
        ):
            message = (
                f"{ABANDONED} after {len(self.path)} evaluations at {self.best / self.limit:.3g}x "
                f"{HOPELESS_RATIO:g} times a rival's cost, falling less than "
                f"{HOPELESS_FALL:g}-fold in its last {HOPELESS_STEPS} steps"
            )
            raise _Hopeless(
                scipy.optimize.OptimizeResult(
                    x=self.x, fun=self.r, cost=0.5 * self.best, success=False, message=message
                )
            )


class _Basin:
    """The neighbourhood of a search's optimum that a later start's search, once in it,
    would only confirm: within one standard deviation of it in the fit's own metric,
    ``|J (theta - x)|^2 <= sigma^2`` (``J`` the optimum's Jacobian, ``J^T J`` its Gram
    matrix), at a cost within ``2 sigma^2`` of its cost (``sigma^2`` = cost / (n - p), as
    the parameters' std).

    Every fit refines two starts; where both end at the same optimum the second was paid
    for in full, its slow last steps the dearest (indep3 time records: 13 of 41 s of the
    searches). Only a search that ended well (``success``) is a basin: one stopped by its
    evaluations' limit is no optimum.
    """

    def __init__(self, x, gram, cost2, sigma2):
        self.x, self.gram, self.cost2, self.sigma2 = x, gram, cost2, sigma2

    @classmethod
    def of(cls, res, n_theta: int, n_obs: int):
        """The basin of the search result ``res`` (scipy's OptimizeResult), or None."""
        if not res.success or res.get("fun") is None or n_obs <= n_theta:
            return None
        gram = res.get("gram")
        if gram is None:
            jac = res.get("jac")
            if jac is None:
                return None
            jac = np.asarray(jac)
            gram = jac.T @ jac
        cost2 = float(res.fun @ res.fun)
        sigma2 = cost2 / (n_obs - n_theta)
        if not (np.all(np.isfinite(gram)) and sigma2 > 0):
            return None
        return cls(np.array(res.x, float), np.asarray(gram, float), cost2, sigma2)

    def check(self, theta, r) -> None:
        """Raises :class:`_SameBasin` where ``theta`` (its residual ``r``) lies in it."""
        d = np.asarray(theta, float) - self.x
        if float(d @ self.gram @ d) > self.sigma2:
            return
        if float(r @ r) <= self.cost2 + 2 * self.sigma2:
            raise _SameBasin


class _Coordinates:
    """The coordinates a search runs in: theta itself, or ``u = log theta`` for the
    parameters a structure marks (``log_floor(problem, base)`` -> (n_theta,) floors, NaN
    where theta stays linear).

    In ``u`` the bounds are ``[log max(floor, lo), log hi]``, the Jacobian and normal
    equations are the chain rule's (``d theta / d u = theta``), and the result is mapped
    back to theta (``x``, ``jac``, ``gram``); a search that ends at the floor ends at the
    parameter's own lower bound (a lag's: no lag on that channel).
    """

    def __init__(self, lo, hi, floor=None):
        self.lo, self.hi = lo, hi
        self.log = None if floor is None else np.isfinite(floor)
        if self.log is not None and not np.any(self.log):
            self.log = None
        if self.log is not None:
            self.floor = np.where(self.log, np.maximum(floor, lo), lo)

    @classmethod
    def of(cls, structure, problem, base, lo, hi):
        fn = getattr(structure, "log_floor", None)
        return cls(lo, hi, None if fn is None else np.asarray(fn(problem, base), float))

    def theta(self, u):
        return u if self.log is None else np.where(self.log, np.exp(u), u)

    def search(self, residual, normal, th0, max_nfev, structure, jac=None):
        lo, hi = self.lo, self.hi
        if self.log is None:
            return _search(residual, normal, th0, lo, hi, max_nfev, structure, jac)
        L = self.log
        ulo = np.where(L, np.log(self.floor), lo)
        uhi = np.where(L, np.log(np.maximum(hi, self.floor * (1 + 1e-9))), hi)
        inner = 1e-3 * (uhi - ulo)
        u0 = np.where(L, np.log(np.clip(th0, self.floor, hi)), th0)
        u0 = np.clip(u0, ulo + inner, uhi - inner)

        def res_u(u):
            return residual(self.theta(u))

        def dtheta(u):  # d theta / d u
            return np.where(L, np.exp(u), 1.0)

        normal_u = None
        if normal is not None:

            def chained(u, r):
                H, g = normal(self.theta(u), r)
                d = dtheta(u)
                return H * np.outer(d, d), g * d

            normal_u = _Normal(chained, normal.tolerances)
        jac_u = None
        if jac is not None:

            def jac_u(u, res, r, lo_u, hi_u):
                return jac(self.theta(u), residual, r, lo, hi) * dtheta(u)

        res = _search(res_u, normal_u, u0, ulo, uhi, max_nfev, structure, jac_u)
        d = dtheta(res.x)
        # a search ended at the floor: the parameter's own bound (a lag: none on that channel)
        res.x = np.where(L & (res.x <= ulo + inner), lo, self.theta(res.x))
        if res.get("jac") is not None:
            res.jac = np.asarray(res.jac) / d
        if res.get("gram") is not None:
            res.gram = res.gram / np.outer(d, d)
        if res.get("grad") is not None:
            res.grad = res.grad / d
        return res


def _search(residual, normal, x0, lo, hi, max_nfev: int, structure, jac=None):
    """One refinement from ``x0``: Levenberg-Marquardt on ``normal``'s equations where
    there are some (:func:`_normal_equations`), else scipy's trust region (``jac``: an
    analytic Jacobian, :func:`_trust_region_jacobian`; secant updates where the structure
    asks, :func:`_trust_region`)."""
    if normal is not None:
        return levenberg_marquardt(
            residual, normal, x0, lo, hi, max_nfev=max_nfev, **normal.tolerances
        )
    secant = bool(getattr(structure, "secant", False))
    return _trust_region(residual, x0, lo, hi, max_nfev, secant=secant, jac=jac)


def _trust_region(
    residual, x0, lo, hi, max_nfev: int, *, secant: bool = False, jac=None
) -> scipy.optimize.OptimizeResult:
    """scipy's trust-region reflective search from ``x0``; an analytic ``jac(x, residual,
    r, lo, hi)`` where given, else difference quotients, or with ``secant`` per
    :data:`TIME_JACOBIAN`.

    With secant updates (:class:`_SecantJacobian`, from :data:`SECANT_MIN_THETA`
    parameters) a search that ends on an updated Jacobian (its stops, the gradient's and the
    step's, judged a secant's model) is checked with difference quotients at its end (the
    parameters' std needs them there): where the Gauss-Newton step they give would lower
    the cost by more than scipy's ``ftol`` (1e-8) of it, the search is taken up from there.
    ``nfev`` counts both searches.
    """

    def run(x, jac, fun, nfev):
        return scipy.optimize.least_squares(
            fun,
            x,
            jac=jac,
            bounds=(lo, hi),
            method="trf",
            x_scale="jac",
            max_nfev=nfev,
            diff_step=DIFF_STEP,
        )

    if jac is not None:
        last = {}  # trf asks for the Jacobian where it just evaluated the residual

        def fun(x):
            r = residual(x)
            last["x"], last["r"] = np.array(x, float), r
            return r

        def jac_at(x):
            r = last["r"] if np.array_equal(last.get("x"), x) else residual(x)
            return jac(np.array(x, float), residual, r, lo, hi)

        return run(x0, jac_at, fun, max_nfev)
    if not secant or TIME_JACOBIAN != "secant" or np.size(x0) < SECANT_MIN_THETA:
        return run(x0, "2-point", residual, max_nfev)
    secant = _SecantJacobian(residual, lo, hi)
    res = run(x0, secant, secant.fun, max_nfev)
    for _ in range(2):  # a search, and where its end is no optimum one more
        if secant.fresh and np.array_equal(secant.xJ, res.x):
            return res
        J = finite_difference_jacobian(residual, res.x, res.fun, lo, hi)
        res.jac = J
        if res.nfev >= max_nfev or _gauss_newton_gain(J, res.fun) <= 1e-8 * res.cost:
            return res
        secant.prime(res.x, res.fun, J)
        again = run(res.x, secant, secant.fun, max(max_nfev - res.nfev, 2))
        again.nfev += res.nfev
        again.njev += res.njev
        res = again
    if not (secant.fresh and np.array_equal(secant.xJ, res.x)):
        res.jac = finite_difference_jacobian(residual, res.x, res.fun, lo, hi)
    return res


def _gauss_newton_gain(J: np.ndarray, r: np.ndarray) -> float:
    """The cost reduction ``|J dx|^2 / 2`` of the Gauss-Newton step ``dx`` (unbounded)."""
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return np.inf
    dx = np.linalg.lstsq(J, -r, rcond=None)[0]
    Jdx = J @ dx
    return 0.5 * float(Jdx @ Jdx)


def levenberg_marquardt(
    residual,
    normal,
    x0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    max_nfev: int = 100,
    ftol: float = 1e-10,
    xtol: float = 1e-10,
    gtol: float = 1e-10,
) -> scipy.optimize.OptimizeResult:
    """Bounded Levenberg-Marquardt on the normal equations ``normal(x, r) = (J^T J, J^T r)``.

    ``scipy.optimize.least_squares`` (trust-region reflective) takes an SVD of the
    full Jacobian every iteration; with an analytic Jacobian of many rows and few
    columns (beam modal fit: 59 940 x 38) that SVD cost 70 ms per iteration, 5x the
    Jacobian itself. Here a step solves the ``n_theta x n_theta`` system
    ``(J^T J + mu D) dx = -J^T r`` (Marquardt's scaling ``D``: the largest
    ``diag(J^T J)`` seen so far, as MINPACK's ``lmder``), is projected onto the
    bounds, and ``mu`` follows Nielsen's gain-ratio rule (Madsen, Nielsen &
    Tingleff 2004, "Methods for non-linear least squares problems", alg. 3.16).

    Stops (scipy's meanings, tighter defaults: an iteration is cheap): cost reduction,
    measured or predicted by a near Gauss-Newton step, below ``ftol`` relative; step
    below ``xtol`` relative to ``|x|``; scaled gradient below ``gtol``; or ``max_nfev``
    residual evaluations.

    Returns
    -------
    OptimizeResult with ``x``, ``cost`` (half the sum of squares, as scipy), ``gram``
    (``J^T J`` at ``x``), ``grad`` (``J^T r`` at ``x``), ``fun``, ``nfev``, ``njev``,
    ``success``, ``message``.
    """
    x = np.clip(np.asarray(x0, float), lo, hi)
    r = residual(x)
    cost = 0.5 * float(r @ r)
    H, g = normal(x, r)
    nfev, njev = 1, 1
    D = np.maximum(np.diag(H).copy(), np.finfo(float).tiny)
    mu, nu = 1e-3, 2.0
    message, success = "max_nfev reached", False
    while nfev < max_nfev:
        # a parameter on its bound whose gradient pushes it outwards is held there (the
        # active set): the step solves for the others. Solved for all and clipped, the
        # step is not the reduced system's, and a search with a damping on its floor
        # crept by fractions of a noise variance until its budget ran out (the
        # walkthrough's joint refit of a delay, a mode and a pseudo-mode: 300
        # evaluations)
        free = ~_held(x, g, lo, hi)
        if not np.any(free) or np.max(np.abs(g[free]) / np.sqrt(D[free])) <= gtol * max(
            np.sqrt(2 * cost), 1e-300
        ):
            message, success = "gtol satisfied", True
            break
        dx = np.zeros_like(x)
        try:
            dx[free] = np.linalg.solve(H[np.ix_(free, free)] + mu * np.diag(D[free]), -g[free])
        except np.linalg.LinAlgError:
            mu, nu = mu * nu, 2 * nu
            continue
        step = np.clip(x + dx, lo, hi) - x
        if np.linalg.norm(step) <= xtol * (xtol + np.linalg.norm(x)):
            message, success = "xtol satisfied", True
            break
        predicted = -(g @ step + 0.5 * step @ H @ step)
        if 0 <= predicted <= ftol * cost and mu < 1e-2:
            # a near Gauss-Newton step that the local model says gains nothing: converged
            # (saves the residual and Jacobian evaluation that would only confirm it)
            message, success = "ftol satisfied (predicted)", True
            break
        r_new = residual(x + step)
        nfev += 1
        cost_new = 0.5 * float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
        rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
        if rho > 0:
            reduction = cost - cost_new
            x, r, cost = x + step, r_new, cost_new
            H, g = normal(x, r)
            njev += 1
            D = np.maximum(D, np.diag(H))
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if reduction <= ftol * cost:
                message, success = "ftol satisfied", True
                break
        else:
            mu, nu = mu * nu, 2.0 * nu
    return scipy.optimize.OptimizeResult(
        x=x,
        cost=cost,
        gram=H,
        grad=g,
        fun=r,
        nfev=nfev,
        njev=njev,
        success=success,
        message=message,
    )


def parameter_std(
    jac: np.ndarray | None, sigma2: float, *, gram: np.ndarray | None = None, rtol: float = 1e-8
) -> np.ndarray:
    """Standard deviations of least-squares parameters, NaN where the data cannot determine them.

    The covariance is ``sigma2 (J^T J)^-1``, computed from the SVD of the column-scaled
    Jacobian ``J`` (n_obs, n_theta). Directions whose singular value is below ``rtol`` times
    the largest are not determined by the data; a parameter with a component along such a
    direction gets NaN ("undetermined") instead of the meaningless number a pseudo-inverse
    would give.

    ``gram = J^T J`` (n_theta, n_theta) may stand in for ``J`` (a structure that gives the
    normal equations, not the Jacobian): its eigenvalues are the squared singular values,
    resolved down to ``sqrt(eps) ~ 1.5e-8`` of the largest, so ``rtol`` is raised to that.
    """
    if gram is not None:
        gram = np.asarray(gram, float)
        scale = np.sqrt(np.maximum(np.diag(gram), 0.0))
        undetermined = ~(scale > 0)
        s = np.where(undetermined, 1.0, scale)
        lam, V = np.linalg.eigh(gram / np.outer(s, s))
        sv, Vt = np.sqrt(np.maximum(lam[::-1], 0.0)), V[:, ::-1].T
        rtol = max(rtol, np.sqrt(np.finfo(float).eps))
    else:
        jac = np.asarray(jac, float)
        scale = np.linalg.norm(jac, axis=0)
        undetermined = ~(scale > 0)
        Js = jac / np.where(undetermined, 1.0, scale)
        sv, Vt = _right_svd(Js, rtol)
    keep = sv > rtol * (sv[0] if sv.size else 0.0)
    null = Vt[~keep]
    if null.size:
        undetermined |= np.max(np.abs(null), axis=0) > 1e-6
    Vk = Vt[keep] / sv[keep][:, None]
    var = np.sum(Vk**2, axis=0) * sigma2 / np.where(undetermined, 1.0, scale) ** 2
    return np.where(undetermined, np.nan, np.sqrt(var))


def cholesky_qr2(A: np.ndarray, *, with_q: bool = True):
    """Thin QR of a tall ``A`` (n, k), n >> k, by CholeskyQR2: ``(Q or None, R)``.

    Two passes of ``R = chol(A^T A)^T``, ``Q = A R^-1`` (Fukaya et al. 2014): as accurate
    as Householder QR while ``cond(A) < ~1e7``, and 4-10x faster for a tall A (two Gram
    products and small triangular inverses instead of n k^2 Householder updates). Raises
    ``np.linalg.LinAlgError`` when a Gram matrix is not positive definite (A numerically
    rank deficient); callers check ``cond(R)`` for their accuracy needs.
    """
    eye = np.eye(A.shape[1])
    R1 = np.linalg.cholesky(A.T @ A).T
    Q1 = A @ scipy.linalg.solve_triangular(R1, eye)  # A R1^-1 as one GEMM
    R2 = np.linalg.cholesky(Q1.T @ Q1).T
    Q = Q1 @ scipy.linalg.solve_triangular(R2, eye) if with_q else None
    return Q, R2 @ R1


def _right_svd(J: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors of a tall ``J`` (n, k), n >> k.

    The SVD of the small ``R`` of :func:`cholesky_qr2`; 15 ms instead of 140 ms for
    LAPACK's SVD of the beam modal fit's 59 940 x 38 Jacobian (one thread). It is
    accurate while ``cond(J) < ~1e7``; beyond (or where Cholesky fails: a rank-deficient
    J) the full SVD decides which directions are undetermined at ``rtol``.
    """
    if J.shape[0] > 4 * J.shape[1] and J.shape[1] > 0:
        try:
            _, R = cholesky_qr2(J, with_q=False)
            _, sv, Vt = np.linalg.svd(R)
            if np.all(np.isfinite(sv)) and sv[-1] > 1e3 * max(rtol, 1e-10) * sv[0]:
                return sv, Vt
        except np.linalg.LinAlgError:
            pass
    _, sv, Vt = np.linalg.svd(J, full_matrices=False)
    return sv, Vt


def _distinct(points: list[np.ndarray], n: int, span: np.ndarray) -> list[np.ndarray]:
    """Up to n points from the sorted list that differ by > 5 % of the span in some coordinate."""
    span = np.where(np.isfinite(span) & (span > 0), span, 1.0)
    out: list[np.ndarray] = []
    for p in points:
        if all(np.max(np.abs(p - q) / span) > 0.05 for q in out):
            out.append(p)
        if len(out) == n:
            break
    return out


@dataclass(frozen=True)
class Held:
    """``structure`` with its parameters outside ``free`` held at ``theta``'s values.

    A joint refit's cost grows with its parameters (finite differences on a time record):
    a coupled suspension's coupling (2 R n_f + n_f^2 parameters) held while the candidates
    of a later round are compared, and refitted with the one taken
    (:func:`workbench.diagnosis.diagnose._joint_candidates`).
    """

    structure: Any
    theta: tuple[float, ...]
    free: tuple[int, ...]

    @property
    def effect(self) -> str:
        return self.structure.effect

    def full(self, theta) -> np.ndarray:
        """The structure's whole theta from the free parameters' values."""
        out = np.array(self.theta, float)
        out[list(self.free)] = theta
        return out

    def grid(self, problem, base):
        return []

    def bounds(self, problem, base):
        lo, hi = self.structure.bounds(problem, base)
        idx = list(self.free)
        return np.asarray(lo, float)[idx], np.asarray(hi, float)[idx]

    def build(self, theta, problem, base):
        return self.structure.build(self.full(theta), problem, base)

    def jacobian(self, theta, problem, base):
        """The structure's analytic columns of the free parameters, or None (it has none)."""
        fn = getattr(self.structure, "jacobian", None)
        J = fn(self.full(theta), problem, base) if callable(fn) else None
        return None if J is None else J[:, list(self.free)]

    def n_linear(self, base):
        return self.structure.n_linear(base)


@dataclass(frozen=True)
class Composite:
    """Several structures applied in order, fitted jointly (earlier findings refitted).

    Parameters
    ----------
    parts : tuple of Structure
    bases : tuple of ModalModel
        The model before each part at the start values (for each part's bounds).
    """

    parts: tuple
    bases: tuple
    effect: str = "composite"
    theta_names: tuple[str, ...] = ()
    _last: list = field(default_factory=list, compare=False, repr=False)  # see chain

    def _sizes(self, problem) -> list[int]:
        return [len(p.bounds(problem, b)[0]) for p, b in zip(self.parts, self.bases)]

    def grid(self, problem, base):
        return []

    def bounds(self, problem, base):
        lo = [np.asarray(p.bounds(problem, b)[0], float) for p, b in zip(self.parts, self.bases)]
        hi = [np.asarray(p.bounds(problem, b)[1], float) for p, b in zip(self.parts, self.bases)]
        return np.concatenate(lo), np.concatenate(hi)

    def split(self, theta, problem) -> list[np.ndarray]:
        out, i = [], 0
        for n in self._sizes(problem):
            out.append(np.asarray(theta[i : i + n], float))
            i += n
        return out

    def chain(self, theta, problem, base) -> list[Realized]:
        """Realized model after each part.

        The parts up to the first whose theta differs from the last chain's are reused
        (same input model, same values: the same Realized): a finite-difference column of
        a later part rebuilds only from it, and the rebuilt part sees the same model object
        (the problem's caches of that model's misfit then hold). A crosstalk after parts
        with linear parameters has them solved again seeing its coupling
        (:func:`_recoupled`).
        """
        thetas = self.split(theta, problem)
        first = self._first_pass(thetas, problem, base)
        return _recoupled(self.parts, thetas, problem, base, first)

    def _first_pass(self, thetas, problem, base) -> list[Realized]:
        out = []
        model = base
        last = self._last  # [(part's theta bytes, its input model, Realized)]
        for i, (part, th) in enumerate(zip(self.parts, thetas)):
            key = th.tobytes()
            if i < len(last) and last[i][0] == key and last[i][1] is model:
                r = last[i][2]
            else:
                r = part.build(th, problem, model)
                del last[i:]
                last.append((key, model, r))
            out.append(r)
            model = r.model
        return out

    def build(self, theta, problem, base):
        return self.chain(theta, problem, base)[-1]

    def lines(self, problem, base):
        """On FRF data: the residual as the model before the last part minus what the last
        part appended (:meth:`FrfProblem.appended_residual`: an added mode or pseudo-mode,
        the model's residual otherwise), in the residual's own layout; else None."""
        if getattr(problem, "kind", "") != "frf" or not hasattr(problem, "appended_residual"):
            return None

        def residual(theta):
            chain = self.chain(theta, problem, base)
            before = chain[-2].model if len(chain) > 1 else base
            return problem.appended_residual(chain[-1].model, before)

        return _Residual(residual, lambda theta: self.jacobian(theta, problem, base))

    def jacobian(self, theta, problem, base):
        """d residual / d theta (n_obs, n_theta) on FRF data, analytic, or None (differences).

        Where every part moves the model by factors alone (a delay, lags, moved modes: an
        analytic ``jacobian`` hook and no linear parameters), the parts commute: the model
        after all of them is part i applied last, on the others applied to ``base``, so
        part i's columns are its own hook's there. Each such reordering is checked to give
        the chain's model (same modes, feedthrough, delay, lags, coupling); where one does
        not, or a part solves linear parameters from the misfit (an added mode, compliance,
        crosstalk: their solution moves with the other parts), None.
        """
        if getattr(problem, "kind", "") != "frf":
            return None
        if not all(
            callable(getattr(p, "jacobian", None)) and p.n_linear(b) == 0
            for p, b in zip(self.parts, self.bases)
        ):
            return None
        thetas = self.split(theta, problem)
        final = self.chain(theta, problem, base)[-1].model
        columns = []
        for i, part in enumerate(self.parts):
            if thetas[i].size == 0:
                continue
            others = base
            for j, (p, th) in enumerate(zip(self.parts, thetas)):
                if j != i:
                    others = p.build(th, problem, others).model
            if not _same_model(part.build(thetas[i], problem, others).model, final):
                return None
            J = part.jacobian(thetas[i], problem, others)
            if J is None:
                return None
            columns.append(J.T)
        # rows stacked (each part's columns contiguous, see effects._residual_columns): a
        # column-wise hstack into a C-ordered tall array costs more than the columns
        return np.vstack(columns).T

    def n_linear(self, base):
        return sum(p.n_linear(b) for p, b in zip(self.parts, self.bases))


def _same_model(a: ModalModel, b: ModalModel) -> bool:
    """True when ``a`` and ``b`` have the same response: equal modes (kind, frequency,
    damping, numerator), feedthrough, delay, lags and coupling."""

    def same_mode(m, n):
        return m is n or (
            m.kind == n.kind
            and m.freq_hz == n.freq_hz
            and m.damping == n.damping
            and all(np.array_equal(x, y) for x, y in zip(m.numerator(), n.numerator()))
        )

    def same(x, y):
        return (x is None and y is None) or (
            x is not None and y is not None and np.array_equal(x, y)
        )

    return (
        len(a.modes) == len(b.modes)
        and all(same_mode(m, n) for m, n in zip(a.modes, b.modes))
        and np.array_equal(a.D, b.D)
        and a.delay_s == b.delay_s
        and np.array_equal(a.lags("in"), b.lags("in"))
        and np.array_equal(a.lags("out"), b.lags("out"))
        and same(a.T_in, b.T_in)
        and same(a.T_out, b.T_out)
    )


class _Residual:
    """Lines (:func:`structure_lines`) with a residual in the model residual's own layout
    and, where ``jacobian(theta)`` is given and does not return None, its analytic
    Jacobian (n_obs, n_theta) in that layout; else finite differences of the residual."""

    def __init__(self, residual, jacobian=None):
        self.residual = residual
        self.jacobian = jacobian

    def cost(self, theta) -> float:
        r = self.residual(theta)
        return float(r @ r)


#: order in which effects are stacked in a joint fit: the outer factors first, so that the
#: linear parts (mode residues, compliance, coupling) are solved seeing all of them
_STACK_ORDER = {
    "time_delay": 0,
    "actuator_dynamics": 1,
    "sensor_dynamics": 2,
    "modal_mismatch": 3,
    "suspension_stiffness": 4,
    "missing_mode": 5,
    "residual_compliance": 6,
    "crosstalk": 7,
}


def _stack_order(part) -> int:
    order = getattr(part, "stack_order", None)
    return _STACK_ORDER.get(part.effect, 9) if order is None else order


def _matrix_crosstalk(parts: list, thetas: list, problem, base: ModalModel):
    """(parts, thetas) with each :class:`~workbench.diagnosis.effects.Crosstalk` as a
    :class:`~workbench.diagnosis.effects.CrosstalkMatrix` started at the matrix the stack
    of ``thetas`` gives it (:func:`_recoupled`), where another part solves linear
    parameters; else the same ``parts`` and ``thetas`` objects.

    The matrix and those parameters are then one least-squares problem: the search moves
    the matrix, the parts solve theirs under it (variable projection), where alternating
    the two converges slowly when a crosstalk entry and a mode's residue are nearly
    collinear (an indepgen stage record, input crosstalk beside a mode at 814 Hz, fitted
    from the truth on the record: 3.0x, 1.9x and 1.4x the noise floor after 3, 10 and 20
    alternations; the matrix searched, 1.008x, the mode at 813.73 Hz damped 0.00527
    against the truth's 813.74 Hz and 0.00537).
    """
    xt = [
        i
        for i, p in enumerate(parts)
        if p.effect == "crosstalk" and not getattr(p, "matrix_searched", False)
    ]
    if not xt:
        return parts, thetas
    _, realized = stack(parts, thetas, problem, base)
    if not any(r.linear for i, r in enumerate(realized) if parts[i].effect != "crosstalk"):
        return parts, thetas
    from workbench.diagnosis.effects import CrosstalkMatrix

    parts, thetas = list(parts), list(thetas)
    for i in xt:
        T = np.asarray(realized[i].linear["matrix"], float)
        cm = CrosstalkMatrix(side=parts[i].side, n=T.shape[0])
        lo, hi = cm.bounds(problem, base)
        parts[i], thetas[i] = cm, np.clip(cm.theta_of(T), lo, hi)
    return parts, thetas


def stack(parts: list, thetas: list[np.ndarray], problem, base: ModalModel):
    """Build parts on base in stacking order; returns (model, realized per part in the given
    order). A crosstalk after parts with linear parameters: :func:`_recoupled`."""
    order = sorted(range(len(parts)), key=lambda i: _stack_order(parts[i]))
    sorted_parts = [parts[i] for i in order]
    sorted_thetas = [np.asarray(thetas[i], float) for i in order]
    built = _recoupled(
        sorted_parts,
        sorted_thetas,
        problem,
        base,
        _built(sorted_parts, sorted_thetas, problem, base),
    )
    realized = {i: r for i, r in zip(order, built)}
    return built[-1].model, [realized[i] for i in range(len(parts))]


def _built(parts, thetas, problem, base: ModalModel) -> list[Realized]:
    """Each part built on the model the parts before it give, from ``base``."""
    out, model = [], base
    for part, th in zip(parts, thetas):
        out.append(part.build(th, problem, model))
        model = out[-1].model
    return out


def coupled(model: ModalModel, side: str, T: np.ndarray) -> ModalModel:
    """``model`` with the static coupling ``T`` added on ``side`` ("out": ``T T_out``, "in":
    ``T_in T``), where a crosstalk puts it."""
    if side == "out":
        return replace(model, T_out=T if model.T_out is None else T @ model.T_out)
    return replace(model, T_in=T if model.T_in is None else model.T_in @ T)


def coupling_added(model: ModalModel, base: ModalModel, side: str) -> np.ndarray | None:
    """The coupling on ``side`` that :func:`coupled` added to ``base`` to give ``model``
    (None where ``model`` has none there)."""
    if side == "out":
        if model.T_out is None:
            return None
        return model.T_out if base.T_out is None else model.T_out @ np.linalg.inv(base.T_out)
    if model.T_in is None:
        return None
    return model.T_in if base.T_in is None else np.linalg.inv(base.T_in) @ model.T_in


#: passes of the parts under a crosstalk that solve their linear parameters seeing it
#: (:func:`_recoupled`): the first without it, then with the coupling the pass before found
COUPLING_PASSES = 3


def _recoupled(parts, thetas, problem, base: ModalModel, first: list[Realized]) -> list[Realized]:
    """``first`` (the parts built in turn on ``base``), built again under the coupling a
    last crosstalk found where parts before it solve linear parameters; else ``first``.

    A crosstalk is stacked last (its matrix solved seeing every other part), so a part
    before it (a mode's numerators, a compliance) is solved on the misfit without the
    coupling and takes the coupling's share as its own; the crosstalk is then solved on
    that. Alternated (:data:`COUPLING_PASSES`): the parts again on ``base`` with the
    coupling of the pass before (which they see unmixed, see
    :func:`workbench.diagnosis.problem._unmixed_misfit`), the crosstalk again on them. Its
    reported matrix is the coupling it adds to ``base`` in all. A scipy-ZOH oracle, an
    output crosstalk of 8 % beside a compliance: 1.47x the noise floor in one pass, the
    compliance's pseudo-mode standing in for the bias at the image of the model's own mode.
    A joint fit then searches the matrix with the other parameters from there
    (:func:`_matrix_crosstalk`): alternation alone converges slowly where a crosstalk entry
    and a residue are nearly collinear.
    """
    if not (
        len(first) > 1
        and parts[-1].effect == "crosstalk"
        and not getattr(parts[-1], "matrix_searched", False)
        and any(r.linear for r in first[:-1])
    ):
        return first
    out = first
    for _ in range(COUPLING_PASSES - 1):
        coupled = out[-1].model
        under = replace(base, T_out=coupled.T_out, T_in=coupled.T_in)
        out = _built(parts, thetas, problem, under)
    r = out[-1]
    model = r.model
    linear = dict(r.linear)
    linear["matrix"] = coupling_added(model, base, parts[-1].side)
    return out[:-1] + [Realized(model, linear, r.linear_std)]


def _error_or_inf(problem, model) -> float:
    """``problem.error(model)``, inf where the model's simulation overflows (a joint fit's
    trial end with a growing mode: NaN, and RuntimeWarnings on the user's terminal)."""
    with np.errstate(over="ignore", invalid="ignore"):
        e = float(problem.error(model))
    return e if np.isfinite(e) else np.inf


def fit_joint(
    parts: list, thetas: list[np.ndarray], problem, base: ModalModel, *, max_nfev: int = MAX_NFEV
):
    """Refit ``parts`` jointly from ``thetas``; returns one FitResult per part and their bases.

    The parts are stacked in :data:`_STACK_ORDER` (outer factors first). The
    FitResult of part k holds the model with parts 0..k (in the given order,
    stacked) and its error; its cost and parameter count are the joint ones.

    A crosstalk beside parts with linear parameters is refitted once more from that
    optimum with its matrix searched (:func:`_matrix_crosstalk`), and the lower cost is
    kept: the search reaches what alternation approaches slowly (a collinear entry), and
    alternation keeps where the search cannot move (a 5-output beam whose outputs span
    fewer directions than the matrix has entries: the search stopped at 1.18x the floor,
    alternation at 1.09x).
    """
    parts, thetas = _crosstalk_as_given(parts, thetas)
    out, base_of = _fit_stacked(parts, thetas, problem, base, max_nfev)
    matrix_parts, matrix_thetas = _matrix_crosstalk(parts, [f.theta for f in out], problem, base)
    if matrix_parts is parts:
        return out, base_of
    searched, searched_bases = _fit_stacked(matrix_parts, matrix_thetas, problem, base, max_nfev)
    if searched[-1].cost < out[-1].cost:
        return searched, searched_bases
    return out, base_of


def _crosstalk_as_given(parts: list, thetas: list) -> tuple[list, list]:
    """``parts`` with each crosstalk in the form its theta is for: a searched matrix
    (:class:`~workbench.diagnosis.effects.CrosstalkMatrix`) where the theta holds its
    entries, a solved one (:class:`~workbench.diagnosis.effects.Crosstalk`) where it is
    empty (a caller pairs an earlier finding's structure with a joint fit's theta)."""
    from workbench.diagnosis.effects import Crosstalk, CrosstalkMatrix

    parts, thetas = list(parts), [np.asarray(t, float) for t in thetas]
    for i, p in enumerate(parts):
        if p.effect != "crosstalk":
            continue
        searched = getattr(p, "matrix_searched", False)
        if not searched and thetas[i].size:
            n = int(round((1 + np.sqrt(1 + 4 * thetas[i].size)) / 2))
            parts[i] = CrosstalkMatrix(side=p.side, n=n)
        elif searched and not thetas[i].size:
            parts[i] = Crosstalk(side=p.side)
    return parts, thetas


def _fit_stacked(parts: list, thetas: list, problem, base: ModalModel, max_nfev: int):
    """:func:`fit_joint`'s search of ``parts`` stacked, from ``thetas``."""
    order = sorted(range(len(parts)), key=lambda i: _stack_order(parts[i]))
    bases = []
    model = base
    for i in order:
        bases.append(model)
        model = parts[i].build(np.asarray(thetas[i], float), problem, model).model
    comp = Composite(parts=tuple(parts[i] for i in order), bases=tuple(bases))
    lo, hi = comp.bounds(problem, base)
    start = np.clip(np.concatenate([np.asarray(thetas[i], float) for i in order]), lo, hi)
    joint = fit(comp, problem, base, starts=[start], n_starts=1, max_nfev=max_nfev)
    th_sorted = comp.split(joint.theta, problem)
    std_sorted = comp.split(joint.theta_std, problem)
    theta = [None] * len(parts)
    std = [None] * len(parts)
    base_of = [None] * len(parts)
    for k, i in enumerate(order):
        theta[i], std[i], base_of[i] = th_sorted[k], std_sorted[k], comp.bases[k]
    out = []
    for k in range(len(parts)):
        model_k, realized = stack(parts[: k + 1], theta[: k + 1], problem, base)
        r = realized[k]
        lin_std = {key: np.asarray(v) * np.sqrt(joint.sigma2) for key, v in r.linear_std.items()}
        out.append(
            FitResult(
                structure=parts[k],
                theta=theta[k],
                theta_std=std[k],
                realized=Realized(model_k, r.linear, lin_std),
                cost=joint.cost if k == len(parts) - 1 else problem.cost(model_k),
                sigma2=joint.sigma2,
                n_params=joint.n_params,
                error=_error_or_inf(problem, model_k),
                status=joint.status,
            )
        )
    return out, base_of
