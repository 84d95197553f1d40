"""Identification that holds on real records: B, D, x0 by least squares, validation fit.

The regression case is DaISy's CD-player arm (``../shared/realdata/``, beside
the checkout like the shared examples). The references are SLICOT's MOESP
figures from its README (IB01AD/BD + IB01CD, block rows 15, same split).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.signal
from conftest import SHARED_REALDATA, require_shared

from workbench.core.errors import InputError
from workbench.ident import identify_subspace
from workbench.ident.order import gap_verdict, order_where_fit_stops_paying
from workbench.ident.validate import (
    estimate_x0,
    fit_percent,
    least_squares_bd_x0,
    offset_warning,
    remove_offsets,
    simulation_fit,
    split_record,
)
from workbench.io.formats import TimeData, save_measurement

# SLICOT MOESP (IB01AD/BD + IB01CD), block rows 15, README of the shared record
SLICOT_FIT = {4: 71.6, 8: 73.0, 12: 73.2}


# ------------------------------------------------------------------ helpers
def own_simulation(A, B, C, D, u, x0):
    """Plain state recursion, independent of workbench.ident.validate."""
    x = np.array(x0, float)
    y = np.empty((u.shape[0], C.shape[0]))
    for k in range(u.shape[0]):
        y[k] = C @ x + D @ u[k]
        x = A @ x + B @ u[k]
    return y


def known_system(seed=0, n=4, m=2, l=2):
    rng = np.random.default_rng(seed)
    A = np.zeros((n, n))
    for k, z in enumerate([0.95 * np.exp(0.3j), 0.8 * np.exp(1.7j)][: n // 2]):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[z.real, z.imag], [-z.imag, z.real]]
    T = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    A = T @ A @ np.linalg.inv(T)
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((l, n))
    D = rng.standard_normal((l, m))
    x0 = 3.0 * rng.standard_normal(n)
    # coloured input with a mean: low-pass filtered noise plus an offset
    e = rng.standard_normal((1500, m))
    u = scipy.signal.lfilter([0.2], [1.0, -0.8], e, axis=0) + np.array([0.7, -0.4])[:m]
    y = own_simulation(A, B, C, D, u, x0)
    return A, B, C, D, x0, u, y


def frf_d(A, B, C, D, w):
    n = A.shape[0]
    return np.array([C @ np.linalg.solve(np.exp(1j * x) * np.eye(n) - A, B) + D for x in w])


def cd_player() -> TimeData:
    d = np.loadtxt(require_shared(SHARED_REALDATA / "CD_player_arm.dat"))
    return TimeData(fs=1.0, u=d[:, :2], y=d[:, 2:])


# ------------------------------------------------------- analytic, noise-free
def test_least_squares_b_d_x0_recover_a_known_system_exactly():
    """Known A, C; y from a nonzero x0 and a coloured input with a mean: exact B, D, x0."""
    A, B, C, D, x0, u, y = known_system()
    Bh, Dh, x0h = least_squares_bd_x0(A, C, u, y)
    assert np.allclose(Bh, B, atol=1e-9 * np.abs(B).max())
    assert np.allclose(Dh, D, atol=1e-9 * np.abs(D).max())
    assert np.allclose(x0h, x0, atol=1e-8 * np.abs(x0).max())
    # channel scales change nothing but units
    su, sy = np.array([2.0, 0.5]), np.array([3.0, 0.1])
    Bs, Ds, x0s = least_squares_bd_x0(A, C / sy[:, None], u, y, su=su, sy=sy)
    assert np.allclose(Bs / su, B, atol=1e-8 * np.abs(B).max())
    assert np.allclose(sy[:, None] * Ds / su, D, atol=1e-8 * np.abs(D).max())
    assert np.allclose(x0s, x0, atol=1e-8 * np.abs(x0).max())


def test_moesp_is_exact_on_a_record_not_at_rest_with_a_mean_input():
    A, B, C, D, x0, u, y = known_system(seed=1)
    res = identify_subspace(TimeData(fs=1.0, u=u, y=y), method="moesp", block_rows=8, order=4)
    assert "least squares" in res.bd_method
    Ai, Bi, Ci, Di = (
        np.asarray(M, float) for M in (res.model.A, res.model.B, res.model.C, res.model.D)
    )
    w = np.linspace(0.01, 3.1, 40)
    Gt, Gi = frf_d(A, B, C, D, w), frf_d(Ai, Bi, Ci, Di, w)
    assert np.max(np.abs(Gi - Gt)) < 1e-7 * np.max(np.abs(Gt))
    # the estimated x0 (in the model's own basis) reproduces the record
    y_hat = own_simulation(Ai, Bi, Ci, Di, u, res.x0)
    assert np.max(np.abs(y_hat - y)) < 1e-7 * np.max(np.abs(y))
    # the structured projection route cannot: the record does not start at rest
    res_p = identify_subspace(
        TimeData(fs=1.0, u=u, y=y), method="moesp", block_rows=8, order=4, bd="projection"
    )
    assert "projection" in res_p.bd_method


def test_estimate_x0_and_fit_of_a_known_model():
    import control

    A, B, C, D, x0, u, y = known_system(seed=2)
    model = control.ss(A, B, C, D, 1.0)
    assert np.allclose(estimate_x0(model, u, y), x0, atol=1e-8 * np.abs(x0).max())
    f = simulation_fit(model, TimeData(fs=1.0, u=u, y=y))
    assert f.x0_estimated and np.all(f.fit > 100 - 1e-6)
    from_rest = simulation_fit(model, TimeData(fs=1.0, u=u, y=y), estimate=False)
    assert not from_rest.x0_estimated and from_rest.mean < f.mean
    # fit by hand: y = [1, 2, 3], y_sim = [1, 2, 4]: ||e|| = 1, ||y - mean|| = sqrt(2)
    yy = np.array([[1.0], [2.0], [3.0]])
    assert fit_percent(yy, yy + [[0], [0], [1]])[0] == pytest.approx(100 * (1 - 1 / np.sqrt(2)))


def test_closed_loop_methods_keep_the_projection_route():
    rng = np.random.default_rng(3)
    A, B, C, _, _, _, _ = known_system(seed=3)
    r = rng.standard_normal((2000, 2))
    K = 0.05 * np.eye(2)
    x = np.zeros(4)
    u = np.empty_like(r)
    y = np.empty_like(r)
    for k in range(r.shape[0]):
        y[k] = C @ x
        u[k] = r[k] - K @ y[k]
        x = A @ x + B @ u[k]
    res = identify_subspace(
        TimeData(fs=1.0, u=u, y=y, r=r, loop="closed"), method="cl-moesp", block_rows=8
    )
    assert "projection" in res.bd_method and res.x0 is None


# -------------------------------------------------------------- real record
@pytest.fixture(scope="module")
def cd_split():
    return split_record(cd_player(), 0.4)


def test_cd_player_validation_fit_matches_slicot(cd_split):
    """First 60 % identification, last 40 % validation, MOESP, i = 15: within 2 points of SLICOT."""
    ident, val = cd_split
    assert (ident.n_samples, val.n_samples) == (1229, 819)
    results = identify_subspace(ident, method="moesp", block_rows=15, orders=[4, 8])
    for res in results:
        f = simulation_fit(res.model, val)
        assert f.mean >= SLICOT_FIT[res.order] - 2.0, (res.order, f.fit)
    # the gap on this record is not decisive, and is said so
    assert results[0].gap < 3.0
    assert gap_verdict(results[0].gap).startswith("NO clear gap")


def test_cli_validate_orders_and_report(tmp_path, capsys):
    from workbench.cli.main import main

    data = tmp_path / "cd.npz"
    save_measurement(data, cd_player())
    out = tmp_path / "m.npz"
    code = main(
        [
            "identify",
            str(data),
            "--method",
            "moesp",
            "--block-rows",
            "15",
            "--order",
            "4",
            "--validate",
            "0.4",
            "--orders",
            "3:5",
            "--detrend",
            "mean",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "NO clear gap" in text and "validation (order 4)" in text
    assert "initial state by least squares" in text
    assert (tmp_path / "m_orders.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = json.loads((tmp_path / "m.json").read_text())
    assert report["validation"]["initial_state"] == "estimated by least squares"
    assert [row["order"] for row in report["order_scan"]] == [3, 4, 5]
    assert report["order_scan"][1]["mean_fit_percent"] == pytest.approx(
        report["validation"]["mean_fit_percent"]
    )
    assert report["offsets"]["mode"] == "mean" and len(report["offsets"]["y_offset"]) == 2
    assert report["validation"]["mean_fit_percent"] >= SLICOT_FIT[4] - 2.0


def test_cli_orders_needs_a_validation_part(tmp_path, capsys):
    from workbench.cli.main import main

    data = tmp_path / "cd.npz"
    save_measurement(data, cd_player())
    out = tmp_path / "m.npz"
    code = main(["identify", str(data), "--method", "moesp", "--orders", "2:4", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "--orders: expected a validation part" in err
    assert err.count("\n") == 1 and not out.exists()


# ---------------------------------------------------------- offsets, order
def test_offsets_are_warned_removed_and_reversible():
    rng = np.random.default_rng(4)
    N, fs = 4000, 100.0
    t = np.arange(N) / fs
    u = rng.standard_normal((N, 1)) + 2.0
    y = rng.standard_normal((N, 2)) + np.outer(t, [0.05, 0.0]) + [0.0, -1.0]
    data = TimeData(fs=fs, u=u, y=y)
    msg = offset_warning(data)
    assert msg is not None and "\n" not in msg
    assert "u0 (mean" in msg and "y0 (" in msg and "trend" in msg and "y1 (mean" in msg
    clean, off = remove_offsets(data, "linear")
    assert offset_warning(clean) is None
    assert np.allclose(off.y_slope, [0.05, 0.0], atol=0.01)
    back = clean.y + off.y_offset + np.outer(t, off.y_slope)
    assert np.allclose(back, y)
    assert (
        offset_warning(
            TimeData(fs=fs, u=rng.standard_normal((N, 1)), y=rng.standard_normal((N, 1)))
        )
        is None
    )
    with pytest.raises(InputError, match="detrend: expected"):
        remove_offsets(data, "quadratic")


def test_gap_verdict_and_where_more_states_stop_paying():
    assert gap_verdict(73.0).startswith("clear gap")
    assert gap_verdict(5.0).startswith("moderate gap")
    assert gap_verdict(1.75).startswith("NO clear gap")
    assert order_where_fit_stops_paying([2, 3, 4, 5, 6], [50.0, 70.0, 75.5, 76.0, 75.8]) == 4


def test_compare_on_time_data_reports_the_same_fit(cd_split):
    from workbench.validate.compare import compare

    ident, val = cd_split
    res = identify_subspace(ident, method="moesp", block_rows=15, order=4)
    f = simulation_fit(res.model, val)
    notes = [n for n in compare(res.model, val).notes if n.startswith("identification fit")]
    assert notes == ["identification " + f.describe(list(val.output_names))]
    assert f"fit {f.mean:.1f} %" in notes[0]


def test_an_unstable_model_scores_minus_infinity_with_a_reason():
    import control

    A, B, C, D, x0, u, y = known_system(seed=5)
    unstable = control.ss(1.2 * A / np.max(np.abs(np.linalg.eigvals(A))), B, C, D, 1.0)
    f = simulation_fit(unstable, TimeData(fs=1.0, u=u, y=y))
    assert f.mean == -np.inf and "unstable" in f.note and "unstable" in f.describe()
    assert f.as_dict()["note"] == f.note


def test_cli_separate_validation_record(tmp_path, capsys, cd_split):
    from workbench.cli.main import main

    ident, val = cd_split
    a, b = tmp_path / "ident.npz", tmp_path / "val.npz"
    save_measurement(a, ident)
    save_measurement(b, val)
    out = tmp_path / "m.npz"
    args = ["identify", str(a), "--method", "moesp", "--block-rows", "15", "--order", "8"]
    assert main(args + ["--validation", str(b), "--out", str(out)]) == 0
    report = json.loads((tmp_path / "m.json").read_text())
    # the same figure as the split inside one record
    res = identify_subspace(ident, method="moesp", block_rows=15, order=8)
    assert report["validation"]["mean_fit_percent"] == pytest.approx(
        simulation_fit(res.model, val).mean, abs=1e-9
    )
    assert "val.npz" in report["validation"]["source"]
    capsys.readouterr()
    one_output = tmp_path / "one.npz"
    save_measurement(one_output, TimeData(fs=1.0, u=val.u, y=val.y[:, :1]))
    code = main(args + ["--validation", str(one_output), "--out", str(tmp_path / "x.npz")])
    assert code == 2 and "expected 2 inputs and 2 outputs" in capsys.readouterr().err
    code = main(args + ["--validate", "0.4", "--orders", "8-4", "--out", str(tmp_path / "y.npz")])
    assert code == 2 and "--orders: expected A:B" in capsys.readouterr().err


def test_a_periodic_record_is_split_at_a_period_boundary():
    rng = np.random.default_rng(7)
    data = TimeData(
        fs=1.0, u=rng.standard_normal((1000, 1)), y=rng.standard_normal((1000, 1)), period=200
    )
    ident, val = split_record(data, 0.3)
    assert (ident.n_samples, val.n_samples) == (800, 200)
    assert ident.period == val.period == 200
    ident, val = split_record(TimeData(fs=1.0, u=data.u, y=data.y), 0.3)
    assert (ident.n_samples, val.n_samples, ident.period) == (700, 300, None)
