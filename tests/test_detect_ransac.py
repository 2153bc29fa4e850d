"""Sequential RANSAC and total least squares on pixel sets."""
from __future__ import annotations

import numpy as np
import pytest

from graphtrack.detect.ransac import RansacConfig, best_line, fit_line_tls, sequential_ransac
from graphtrack.geometry.lines import line_difference


def points_on(rho, theta, t, noise, rng):
    n = np.array([np.cos(theta), np.sin(theta)])
    d = np.array([-np.sin(theta), np.cos(theta)])
    return rho * n + t[:, None] * d + rng.normal(0, noise, len(t))[:, None] * n


def max_offset(line, rho, theta, t):
    """Largest distance (px) of the true line's points over extent t to the found line."""
    p = points_on(rho, theta, t, 0.0, np.random.default_rng(0))
    return np.max(np.abs(np.cos(line[1]) * p[:, 0] + np.sin(line[1]) * p[:, 1] - line[0]))


@pytest.mark.parametrize("theta", [0.0, 0.3, np.pi / 2, 2.5, np.pi - 0.01])
def test_tls_exact(theta):
    rng = np.random.default_rng(1)
    p = points_on(120.0, theta, np.linspace(-50, 300, 40), 0.0, rng)
    rho_t, th_t = fit_line_tls(p)
    drho, dth = line_difference(rho_t, th_t, 120.0, theta)
    assert abs(drho) < 1e-8 and abs(dth) < 1e-10
    assert 0 <= th_t < np.pi


def test_recovers_line_among_outliers():
    rng = np.random.default_rng(42)
    rho, theta = 210.0, 1.1
    t = rng.uniform(-150, 150, 120)
    inl = points_on(rho, theta, t, 0.25, rng)
    centre = inl.mean(0)
    out = centre + rng.uniform(-160, 160, (240, 2))
    pts = rng.permutation(np.concatenate([inl, out]))
    line, count = best_line(pts, rng=7)
    assert line is not None
    assert max_offset(line, rho, theta, np.linspace(-150, 150, 50)) < 0.2
    assert count >= 100
    # reproducible with the same seed
    line2, count2 = best_line(pts, rng=7)
    np.testing.assert_array_equal(line, line2)
    assert count == count2


def test_sequential_finds_two_lines():
    rng = np.random.default_rng(3)
    a = points_on(100.0, 0.4, rng.uniform(-100, 100, 150), 0.2, rng)
    b = points_on(300.0, 2.0, rng.uniform(-100, 100, 90), 0.2, rng)
    noise = rng.uniform(0, 300, (60, 2))
    lines, counts = sequential_ransac(np.concatenate([a, b, noise]), rng=0)
    assert len(lines) <= 5 and len(lines) == len(counts)
    assert counts[0] >= counts[1]
    found = [min(abs(line_difference(l[0], l[1], r, th)[1]) for r, th in [(100.0, 0.4), (300.0, 2.0)])
             for l in lines[:2]]
    assert max(found) < 0.02
    assert lines.shape[1] == 2 and np.all((lines[:, 1] >= 0) & (lines[:, 1] < np.pi))


def test_vectorised_trials_config():
    rng = np.random.default_rng(5)
    p = points_on(50.0, 2.9, rng.uniform(0, 200, 80), 0.1, rng)
    lines, counts = sequential_ransac(p, RansacConfig(iterations=1, trials=20, threshold=0.5), rng)
    assert len(lines) == 1 and counts[0] >= 75


def test_small_and_degenerate_sets():
    assert best_line(np.zeros((0, 2))) == (None, 0)
    assert best_line(np.array([[1.0, 2.0], [3.0, 4.0]])) == (None, 0)
    line, n = best_line(np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]))
    assert line is None and n == 0          # identical pixels define no line
    lines, counts = sequential_ransac(np.array([[np.nan, 1.0], [0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]))
    assert len(lines) == 1 and counts[0] == 3


def test_groups_make_samples_span_two_endpoint_discs():
    """Two filled discs (radius 10 px, integer pixels, as E_e of a thick heatmap) at
    the ends of a 400 px edge, the second sparse: with the discs as groups every
    hypothesis spans the edge and the best line is the edge through both."""
    theta = 2.07
    n, d = np.array([np.cos(theta), np.sin(theta)]), np.array([-np.sin(theta), np.cos(theta)])
    ends = [np.array([300.0, 300.0]), np.array([300.0, 300.0]) + 400 * d]
    yy, xx = np.mgrid[-10:11, -10:11]
    disc = np.stack([xx.ravel(), yy.ravel()], 1)[(xx ** 2 + yy ** 2).ravel() <= 100]
    pts = np.concatenate([np.round(ends[0]) + disc, np.round(ends[1]) + disc[::5]])
    groups = np.repeat([0, 1], [len(disc), len(disc[::5])])
    rho = float(n @ (np.round(ends[0]) + np.round(ends[1])) / 2)
    spanning, _ = best_line(pts, rng=0, groups=groups)
    assert abs(line_difference(spanning[0], spanning[1], rho, theta)[1]) < 0.02


def test_tls_matches_the_moment_form_and_has_no_line_without_points():
    """fit_line_tls (scalar path) equals tls_from_moments on the centred moments, and an
    empty, weightless or non-finite set gives (nan, nan) rather than an exception."""
    from graphtrack.detect.ransac import tls_from_moments
    rng = np.random.default_rng(3)
    for _ in range(200):
        p = rng.normal(size=(20, 2)) * [50.0, 3.0] @ np.array([[0.6, 0.8], [-0.8, 0.6]]) + rng.normal(size=2) * 100
        c = p.mean(0)
        q = p - c
        x, y = q[:, 0], q[:, 1]
        w = np.ones(len(p))
        rho, theta = tls_from_moments(w.sum(), w @ x, w @ y, w @ (x * x), w @ (x * y), w @ (y * y))
        rho = rho + np.cos(theta) * c[0] + np.sin(theta) * c[1]
        np.testing.assert_allclose(fit_line_tls(p), [rho, theta], rtol=0, atol=1e-9)
    with np.errstate(all="ignore"):
        for bad in (np.zeros((0, 2)), np.array([[np.nan, 1.0], [2.0, 3.0]])):
            assert np.all(np.isnan(fit_line_tls(bad)))
        assert np.all(np.isnan(fit_line_tls(np.array([[0.0, 0.0], [1.0, 1.0]]), np.zeros(2))))
