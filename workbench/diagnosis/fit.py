"""One fitting engine for every effect: weighted nonlinear least squares with variable projection.

A :class:`Structure` is a parameterized model on top of a base model: its
nonlinear parameters ``theta`` (a delay, a frequency and damping, cutoffs) are
found by Levenberg-Marquardt-type trust-region least squares
(``scipy.optimize.least_squares``, finite-difference Jacobian: ``theta`` has at
most a handful of entries), while the parameters that enter linearly (mode
residues, compliance and coupling matrices) are solved inside every residual
evaluation by the problem's closed-form linear fits (variable projection,
Golub & Pereyra 1973). Start points come from a coarse grid of ``theta``
evaluated by the same projected cost.

Data flow::

    Structure.grid ──> cost on the grid ──> best starts ──> least_squares
         │                                        (residual = problem.residual(Structure.build(theta)))
         └──────────── FitResult(model, theta ± std, linear parts ± std, cost, error)
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import scipy.optimize

from workbench.diagnosis.modal import ExtendedModel

__all__ = ["Structure", "Realized", "FitResult", "fit", "screen"]


@dataclass(frozen=True)
class Realized:
    """A structure evaluated at one theta: the model and the linear parameters it solved."""

    model: ExtendedModel
    linear: dict[str, Any] = field(default_factory=dict)
    linear_std: dict[str, Any] = field(default_factory=dict)


class Structure(Protocol):
    """A parameterized effect on top of a base model (see module docstring)."""

    effect: str
    theta_names: tuple[str, ...]

    def grid(self, problem, base: ExtendedModel) -> list[np.ndarray]:
        """Candidate start points, each of shape (n_theta,)."""

    def bounds(self, problem, base: ExtendedModel) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of theta."""

    def build(self, theta: np.ndarray, problem, base: ExtendedModel) -> Realized:
        """The augmented model at theta, its linear parts solved by projection."""

    def n_linear(self, base: ExtendedModel) -> int:
        """Number of linear parameters (for the information criterion)."""

    def report(self, fit_result: FitResult, problem, base: ExtendedModel) -> tuple[dict, dict]:
        """Physical parameters and their standard deviations, JSON-ready."""


@dataclass(frozen=True)
class FitResult:
    """Outcome of fitting one structure.

    Attributes
    ----------
    theta, theta_std : (n_theta,) arrays
        Nonlinear parameters and standard deviations (Jacobian, residual-scaled).
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

    @property
    def model(self) -> ExtendedModel:
        return self.realized.model

    @property
    def effect(self) -> str:
        return self.structure.effect


def screen(structure: Structure, problem, base: ExtendedModel) -> tuple[float, list[np.ndarray]]:
    """Projected cost on the structure's grid: (lowest cost, grid points sorted by cost).

    A structure without nonlinear parameters is evaluated once (its fit is exact).
    """
    lo, hi = (np.asarray(b, float) for b in structure.bounds(problem, base))
    if lo.size == 0:
        return problem.cost(structure.build(np.zeros(0), problem, base).model), []
    grid = [np.clip(np.asarray(g, float), lo, hi) for g in structure.grid(problem, base)]
    costs = []
    for g in grid:
        try:
            costs.append(problem.cost(structure.build(g, problem, base).model))
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            costs.append(np.inf)
    order = np.argsort(costs)
    return float(costs[order[0]]), [grid[i] for i in order]


def fit(
    structure: Structure,
    problem,
    base: ExtendedModel,
    *,
    starts: list[np.ndarray] | None = None,
    n_starts: int = 2,
    max_nfev: int = 60,
) -> FitResult:
    """Fit ``structure`` on top of ``base`` to the data of ``problem``.

    Parameters
    ----------
    structure : Structure
    problem : FrfProblem or TimeProblem
    base : ExtendedModel
        The model to augment (the nominal, or the nominal with earlier findings).
    starts : list of (n_theta,) arrays, optional
        Start points sorted best first (from :func:`screen`); by default the grid is screened here.
    n_starts : int
        Number of distinct start points refined by least squares.
    max_nfev : int
        Residual evaluations per refinement.
    """

    def residual(theta):
        return problem.residual(structure.build(theta, problem, base).model)

    lo, hi = (np.asarray(b, float) for b in structure.bounds(problem, base))
    n_theta = lo.size
    status = "ok"
    if n_theta == 0:
        theta = np.zeros(0)
        jac = np.zeros((problem.n_obs, 0))
    else:
        if starts is None:
            _, starts = screen(structure, problem, base)
        starts = _distinct(starts, n_starts, hi - lo)
        best = None
        for th0 in starts:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = scipy.optimize.least_squares(
                    residual,
                    th0,
                    bounds=(lo, hi),
                    method="trf",
                    x_scale="jac",
                    max_nfev=max_nfev,
                    diff_step=1e-4,
                )
            if best is None or res.cost < best.cost:
                best = res
        theta, jac = best.x, best.jac
        if not best.success:
            status = f"least squares stopped: {best.message}"
    realized = structure.build(theta, problem, base)
    r = problem.residual(realized.model)
    cost = float(r @ r)
    n_params = n_theta + structure.n_linear(base)
    sigma2 = cost / max(problem.n_obs - n_params, 1)
    if n_theta:
        JtJ = jac.T @ jac
        cov = np.linalg.pinv(JtJ) * sigma2
        theta_std = np.sqrt(np.abs(np.diag(cov)))
    else:
        theta_std = np.zeros(0)
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
