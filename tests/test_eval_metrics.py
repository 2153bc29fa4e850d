"""Evaluation metrics against hand-computed values."""
import numpy as np
import pytest

from graphtrack.eval import metrics as M
from graphtrack.eval.metrics import paired_difference
from graphtrack.geometry.se3 import bw_to_matrix


def test_accumulated_error_is_running_mean():
    e = np.array([2.0, 4.0, 6.0, np.nan, 8.0])
    np.testing.assert_allclose(M.accumulated_error(e), [2.0, 3.0, 4.0, 4.0, 5.0])
    assert np.isnan(M.accumulated_error([np.nan, 1.0])[0])


def test_summary_percentiles():
    v = np.arange(1, 101, dtype=float)  # 1..100
    s = M.summary(np.append(v, np.nan))
    assert s["mean"] == pytest.approx(50.5)
    assert s["median"] == pytest.approx(50.5)
    assert s["p95"] == pytest.approx(95.05)  # linear interpolation: 1 + 0.95 * 99
    assert s["std"] == pytest.approx(np.sqrt((100 ** 2 - 1) / 12))


def test_tip_metrics_px_and_percent_of_diagonal():
    labels = {0: np.array([0.0, 0.0]), 1: np.array([10.0, 10.0]), 5: np.array([1.0, 1.0])}
    tips = np.array([[3.0, 4.0], [10.0, 10.0]])  # errors 5, 0; frame 5 not tracked
    doc = M.tip_metrics([0, 1], tips, labels, diagonal=500.0)
    assert doc["frames_scored"] == 2
    assert doc["tip_error_px"]["mean"] == pytest.approx(2.5)
    assert doc["tip_error_percent_diagonal"]["mean"] == pytest.approx(0.5)


def test_rotation_and_translation_error_of_known_perturbation():
    E_true = bw_to_matrix(np.array([0.1, -0.02, 0.15, 0.3, -0.1, 0.2]))
    # 3 degrees about z and 4 mm along x, applied on the left (camera frame)
    d = bw_to_matrix(np.array([0.004, 0.0, 0.0, 0.0, 0.0, np.radians(3.0)]))
    E_est = d @ E_true
    t, r = M.pose_errors(E_est[None], E_true[None])
    assert r[0] == pytest.approx(3.0, abs=1e-9)
    # translation of d @ E_true = R_d t_true + b_d
    expected = 1e3 * np.linalg.norm(d[:3, :3] @ E_true[:3, 3] + d[:3, 3] - E_true[:3, 3])
    assert t[0] == pytest.approx(expected)


def test_nees_with_known_perturbation():
    E_est = bw_to_matrix(np.array([0.1, 0.0, 0.1, 0.0, 0.2, 0.0]))
    xi = np.array([0.002, -0.001, 0.0, 0.01, 0.0, -0.02])
    E_true = bw_to_matrix(xi) @ E_est
    np.testing.assert_allclose(M.perturbation(E_true, E_est), xi, atol=1e-12)
    std = np.array([0.001, 0.001, 0.001, 0.01, 0.01, 0.01])
    v = M.nees(E_true[None], E_est[None], std[None])
    assert v[0] == pytest.approx(4 + 1 + 0 + 1 + 0 + 4)
    assert np.isnan(M.nees(E_true[None], E_est[None], np.zeros((1, 6)))[0])


def test_runtime_metrics():
    r = M.runtime_metrics([10.0, 20.0, 30.0, np.nan])
    assert r["median"] == pytest.approx(20.0)
    assert r["max"] == pytest.approx(30.0)
    assert r["fps_median"] == pytest.approx(50.0)


def test_truth_errors_and_3d_tip(tmp_path):
    from graphtrack.io.trajectory import TrajectoryWriter, read_trajectory

    E_true = [bw_to_matrix(np.array([0.0, 0.0, 0.2, 0.0, 0.0, 0.0 + 0.01 * k])) for k in range(3)]
    offset = np.eye(4)
    offset[0, 3] = 0.002  # 2 mm in x
    for name, Es in (("truth", E_true), ("est", [offset @ E for E in E_true])):
        (tmp_path / name).mkdir()
        with TrajectoryWriter(tmp_path / name, extra_columns=M.STD_COLUMNS) as w:
            for k, E in enumerate(Es):
                w.write(k, 0.1 * k, E, (100.0 + k, 50.0), 10.0,
                        {c: 0.001 for c in M.STD_COLUMNS})
    est = read_trajectory(tmp_path / "est" / "trajectory.csv")
    truth = read_trajectory(tmp_path / "truth" / "trajectory.csv")
    tips = {k: np.array([0.0, 0.01, 0.0]) for k in range(3)}
    errs = M.truth_errors(est, truth, tips)
    np.testing.assert_allclose(errs["trans_mm"], 2.0)
    np.testing.assert_allclose(errs["tip_mm"], 2.0)
    np.testing.assert_allclose(errs["rot_deg"], 0.0, atol=1e-6)
    np.testing.assert_allclose(errs["nees"], 4.0, rtol=1e-6)  # (2 mm / 1 mm)^2
    doc = M.truth_metrics(errs)
    assert doc["translation_error_mm"]["mean"] == pytest.approx(2.0)
    assert doc["nees"]["dof"] == 6


def test_3d_tip_error_splits_into_depth_and_lateral(tmp_path):
    """Hand-computed: the estimate's tip 3 mm beyond the true tip along its viewing ray
    and 4 mm across it: depth 3, lateral 4, 3-D 5 mm; 3 mm nearer: depth -3."""
    from graphtrack.io.trajectory import TrajectoryWriter, read_trajectory

    tip = np.array([0.02, 0.0, 0.0])                       # base frame, m
    E_true = np.eye(4)
    E_true[2, 3] = 0.2                                     # true tip (0.02, 0, 0.2) m
    ray = np.array([0.02, 0.0, 0.2]) / np.linalg.norm([0.02, 0.0, 0.2])
    Es = {"truth": [E_true, E_true]}
    Es["est"] = []
    for depth in (3e-3, -3e-3):
        E = E_true.copy()
        E[:3, 3] += depth * ray + np.array([0.0, 4e-3, 0.0])
        Es["est"].append(E)
    for name, poses in Es.items():
        (tmp_path / name).mkdir()
        with TrajectoryWriter(tmp_path / name) as w:
            for k, E in enumerate(poses):
                w.write(k, 0.1 * k, E, (100.0, 50.0), 10.0)
    errs = M.truth_errors(read_trajectory(tmp_path / "est" / "trajectory.csv"),
                          read_trajectory(tmp_path / "truth" / "trajectory.csv"), {0: tip, 1: tip})
    np.testing.assert_allclose(errs["tip_mm"], 5.0)
    np.testing.assert_allclose(errs["tip_depth_mm"], [3.0, -3.0])
    np.testing.assert_allclose(errs["tip_lateral_mm"], 4.0)
    doc = M.truth_metrics(errs)
    assert doc["tip_error_3d_depth_mm"]["mean"] == pytest.approx(3.0)
    assert doc["tip_error_3d_lateral_mm"]["mean"] == pytest.approx(4.0)
    M.write_errors_csv(tmp_path / "e.csv", errs)
    head = (tmp_path / "e.csv").read_text().splitlines()[0].split(",")
    assert head[-2:] == ["tip_depth_mm", "tip_lateral_mm"]


# -- paired_difference: oracles from normal theory ------------------------------------
def test_paired_difference_of_a_constant_shift_is_that_shift_with_no_spread():
    a = np.linspace(1.0, 3.0, 90)
    r = paired_difference(a, a - 0.25)
    assert r["mean"] == pytest.approx(0.25) and r["frames"] == 90
    assert r["low"] == pytest.approx(0.25) and r["high"] == pytest.approx(0.25)


@pytest.mark.slow
def test_paired_difference_interval_matches_normal_theory_for_independent_frames():
    rng = np.random.default_rng(3)
    n = 4000
    d = 0.5 + rng.normal(size=n)
    r = paired_difference(d, np.zeros(n), block=1, resamples=4000)
    half = 1.959964 * d.std() / np.sqrt(n)          # the normal-theory 95 % half-width
    assert r["mean"] == pytest.approx(d.mean())
    assert (r["high"] - r["low"]) / 2 == pytest.approx(half, rel=0.1)
    assert r["low"] < d.mean() < r["high"]


@pytest.mark.slow
def test_paired_difference_blocks_widen_the_interval_for_persistent_errors():
    # 100 independent N(0, 1) values, each held for 30 frames. Oracle: the
    # moving-block bootstrap's mean is the average of k = n / L blocks drawn
    # uniformly from the n - L + 1 moving blocks, so its variance is exactly
    # var(moving-block means) / k (no resampling needed); with 2000 draws the
    # percentile interval's half-width is 1.96 times its square root to ~5 %.
    rng = np.random.default_rng(4)
    d = np.repeat(rng.normal(size=100), 30)
    n, L = len(d), 30
    block_means = np.convolve(d, np.ones(L) / L, mode="valid")       # the n - L + 1 moving blocks
    exact_half = 1.959964 * np.sqrt(block_means.var() / (n // L))
    wide = paired_difference(d, np.zeros_like(d), block=L, resamples=4000)
    assert (wide["high"] - wide["low"]) / 2 == pytest.approx(exact_half, rel=0.08)
    # frames counted as independent claim an interval several times narrower
    narrow = paired_difference(d, np.zeros_like(d), block=1, resamples=4000)
    assert (narrow["high"] - narrow["low"]) < 0.5 * (wide["high"] - wide["low"])


def test_paired_difference_refuses_unpaired_errors_and_too_few_frames_for_its_blocks():
    with pytest.raises(ValueError, match="same frames"):
        paired_difference(np.ones(1), np.zeros(10))
    r = paired_difference(np.arange(40.0), np.zeros(40), block=30)     # fewer than 2 blocks
    assert r["mean"] == pytest.approx(19.5) and r["frames"] == 40
    assert np.isnan(r["low"]) and np.isnan(r["high"])


def test_paired_difference_skips_unscored_frames_and_reports_nan_when_none_are_shared():
    a = np.array([1.0, np.nan, 3.0, 4.0])
    b = np.array([0.0, 1.0, np.nan, 2.0])
    r = paired_difference(a, b, block=1)
    assert r["frames"] == 2 and r["mean"] == pytest.approx(1.5)
    assert np.isnan(paired_difference([np.nan], [1.0])["mean"])
