"""Defects fixed in the fitting engine and around it (core issue): numerical failures vs bugs,
undetermined parameters, non-converged fits, loud imports, no global switches."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from workbench.core.blas import limited_blas
from workbench.core.errors import InputError
from workbench.diagnosis.fit import Realized, parameter_std, screen


class _Problem:
    """A problem whose cost is the squared distance of the model (a number) to 3."""

    n_obs = 10

    def cost(self, model):
        return float((model - 3.0) ** 2)


class _Structure:
    effect = "fake"
    theta_names = ("a",)

    def __init__(self, fail_at=(), exc=np.linalg.LinAlgError):
        self.fail_at, self.exc = set(fail_at), exc

    def grid(self, problem, base):
        return [np.array([v]) for v in (0.0, 1.0, 2.0, 4.0, 5.0)]

    def bounds(self, problem, base):
        return np.array([0.0]), np.array([5.0])

    def build(self, theta, problem, base):
        if float(theta[0]) in self.fail_at:
            raise self.exc("singular projection")
        return Realized(model=float(theta[0]))

    def n_linear(self, base):
        return 0


def test_screen_scores_numerical_failures_as_infinite_and_counts_them():
    sc = screen(_Structure(fail_at={2.0, 4.0}), _Problem(), None)
    assert sc.n_failed == 2
    # costs 9, 4, (1 failed), (1 failed), 4: the best of what is left is 4, at theta = 1 or 5
    assert sc.cost == pytest.approx(4.0)
    assert float(sc.starts[0][0]) in (1.0, 5.0)
    cost, starts = sc  # unpacks as (cost, starts)
    assert cost == sc.cost and len(starts) == 5


def test_screen_lets_a_bug_inside_an_effect_propagate():
    # InputError is a ValueError; it used to be caught and the effect silently dropped
    with pytest.raises(InputError):
        screen(_Structure(fail_at={1.0}, exc=InputError), _Problem(), None)
    with pytest.raises(ValueError):
        screen(_Structure(fail_at={1.0}, exc=ValueError), _Problem(), None)


def test_parameter_std_matches_linear_regression_closed_form():
    rng = np.random.default_rng(3)
    X = rng.standard_normal((200, 3)) * np.array([1.0, 1e3, 1e-4])  # badly scaled columns
    sigma2 = 0.7
    std = parameter_std(X, sigma2)
    ref = np.sqrt(np.diag(np.linalg.inv(X.T @ X)) * sigma2)
    np.testing.assert_allclose(std, ref, rtol=1e-9)


def test_parameter_std_says_undetermined_instead_of_a_number():
    rng = np.random.default_rng(4)
    x = rng.standard_normal(100)
    # parameters 0 and 1 enter only as their sum; parameter 2 does not enter at all
    J = np.column_stack([x, x, np.zeros(100), rng.standard_normal(100)])
    std = parameter_std(J, 1.0)
    assert np.isnan(std[0]) and np.isnan(std[1]) and np.isnan(std[2])
    assert np.isfinite(std[3]) and std[3] > 0
    # the old sqrt(abs(diag(pinv))) gave finite numbers for all three undetermined ones
    old = np.sqrt(np.abs(np.diag(np.linalg.pinv(J.T @ J))))
    assert np.all(np.isfinite(old[:2]))


def test_finding_json_marks_undetermined_and_carries_fit_status():
    from workbench.diagnosis.diagnose import Finding

    f = Finding(
        effect="time_delay",
        inputs=(0,),
        outputs=(0,),
        band_hz=(1.0, 2.0),
        parameters={"delay_s": 2e-4, "cutoff_hz": [100.0, 200.0]},
        parameters_std={"delay_s": float("nan"), "cutoff_hz": [1.0, float("nan")]},
        error_after=0.1,
        explanation="x",
        fit_status="least squares stopped: max_nfev",
    )
    js = f.to_json()
    assert js["parameters_std"] == {"delay_s": "undetermined", "cutoff_hz": [1.0, "undetermined"]}
    assert js["fit_status"].startswith("least squares stopped")
    assert f.undetermined == ("delay_s", "cutoff_hz")


def test_limited_blas_is_scoped_and_checked():
    from threadpoolctl import threadpool_info

    before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    with limited_blas(1):
        inside = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
        assert all(n == 1 for n in inside)
    after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    assert after == before
    with limited_blas(None):
        pass
    with pytest.raises(InputError, match="blas_threads"):
        limited_blas(0)


def test_cli_fails_loudly_on_a_broken_command_import(monkeypatch):
    cli = importlib.import_module("workbench.cli.main")
    monkeypatch.setattr(cli, "COMMANDS", (*cli.COMMANDS, "no_such_command_module"))
    with pytest.raises(ModuleNotFoundError):
        cli.build_parser()


def test_diagnosis_plots_leave_the_matplotlib_backend_alone(tmp_path):
    import matplotlib

    from workbench.diagnosis.modal import decompose
    from workbench.diagnosis.plots import write_plots
    from workbench.io.formats import FrfData

    backend = matplotlib.get_backend()
    import control

    sys = control.ss(
        [[0, 1], [-((2 * np.pi * 50) ** 2), -2 * 0.02 * 2 * np.pi * 50]], [[0], [1]], [[1, 0]], 0
    )
    em = decompose(sys)
    f = np.geomspace(5, 500, 50)
    data = FrfData(freq=f, G=1.05 * em.frf(f), input_names=("u",), output_names=("y",))
    written = write_plots(tmp_path, data, em, em, title="t")
    assert all(p.exists() and p.stat().st_size > 1000 for p in written)
    assert matplotlib.get_backend() == backend
