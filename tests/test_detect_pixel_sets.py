"""E_e and E_l against a brute-force per-pixel reference on a small heatmap."""
from __future__ import annotations

import numpy as np
import pytest

from graphtrack.detect.pixel_sets import endpoint_set, endpoints_set, line_set


def brute_endpoint(H, e, alpha, beta, shape=None):
    h, w = H.shape if H is not None else shape
    out = []
    for y in range(h):
        for x in range(w):
            if (H is None or H[y, x] >= beta) and (x - e[0]) ** 2 + (y - e[1]) ** 2 <= alpha ** 2:
                out.append((x, y))
    return np.array(out, float).reshape(-1, 2)


def brute_line(H, seg, alpha, beta, shape=None):
    h, w = H.shape if H is not None else shape
    a, b = np.array(seg[:2], float), np.array(seg[2:], float)
    out = []
    for y in range(h):
        for x in range(w):
            if H is not None and H[y, x] < beta:
                continue
            p = np.array([x, y], float)
            ab = b - a
            L2 = ab @ ab
            t = 0.0 if L2 == 0 else min(1.0, max(0.0, (p - a) @ ab / L2))
            if np.linalg.norm(p - (a + t * ab)) <= alpha:
                out.append((x, y))
    return np.array(out, float).reshape(-1, 2)


def as_set(p):
    return {(float(x), float(y)) for x, y in np.asarray(p).reshape(-1, 2)}


@pytest.fixture(scope="module")
def heatmap():
    rng = np.random.default_rng(0)
    return rng.random((40, 56)).astype(np.float32)


ENDPOINTS = [(20.0, 15.0), (0.0, 0.0), (55.3, 39.7), (-5.0, 10.0), (70.0, 70.0), (10.5, 20.5)]
SEGMENTS = [(5.0, 5.0, 50.0, 30.0), (-10.0, 20.0, 70.0, 22.0), (30.0, 0.0, 30.0, 39.0),
            (12.0, 12.0, 12.0, 12.0), (50.2, 3.7, 8.9, 35.1), (100.0, 100.0, 120.0, 130.0)]


@pytest.mark.parametrize("e", ENDPOINTS)
@pytest.mark.parametrize("alpha,beta", [(10.0, 0.9), (4.5, 0.5), (0.0, 0.0)])
def test_endpoint_set_matches_brute_force(heatmap, e, alpha, beta):
    got = endpoint_set(heatmap, e, alpha, beta)
    ref = brute_endpoint(heatmap, e, alpha, beta)
    assert got.shape[1] == 2 and got.dtype == float
    assert len(got) == len(as_set(got))              # no duplicates
    assert as_set(got) == as_set(ref)


@pytest.mark.parametrize("seg", SEGMENTS)
@pytest.mark.parametrize("alpha,beta", [(10.0, 0.9), (3.0, 0.3)])
def test_line_set_matches_brute_force(heatmap, seg, alpha, beta):
    got = line_set(heatmap, seg, alpha, beta)
    assert as_set(got) == as_set(brute_line(heatmap, seg, alpha, beta))
    assert len(got) == len(as_set(got))


@pytest.mark.parametrize("seg", SEGMENTS)
def test_endpoints_union(heatmap, seg):
    got = endpoints_set(heatmap, seg, 10.0, 0.6)
    ref = as_set(brute_endpoint(heatmap, seg[:2], 10.0, 0.6)) | as_set(brute_endpoint(heatmap, seg[2:], 10.0, 0.6))
    assert as_set(got) == ref
    assert len(got) == len(ref)                      # overlapping discs counted once


def test_no_heatmap_means_ones(heatmap):
    shape = heatmap.shape
    assert as_set(endpoint_set(None, (20.0, 15.0), 6.0, 0.9, shape)) == \
        as_set(brute_endpoint(None, (20.0, 15.0), 6.0, 0.9, shape))
    assert as_set(line_set(None, SEGMENTS[0], 4.0, 0.9, shape)) == \
        as_set(brute_line(None, SEGMENTS[0], 4.0, 0.9, shape))
    # without a shape, only x, y >= 0 are enforced
    p = endpoint_set(None, (2.0, 2.0), 3.0)
    assert p.min() >= 0 and len(p) == len(brute_endpoint(None, (2.0, 2.0), 3.0, 0.0, (10, 10)))


def test_degenerate_inputs(heatmap):
    assert endpoint_set(heatmap, (np.nan, 3.0)).shape == (0, 2)
    assert line_set(heatmap, (np.nan, 0, 1, 1)).shape == (0, 2)
    assert line_set(np.zeros((5, 5), np.float32), (0, 0, 4, 4)).shape == (0, 2)
    assert endpoints_set(np.zeros((0, 0), np.float32), (0, 0, 4, 4)).shape == (0, 2)


def _band(rng, a, angle, offset, n=400, length=120.0, spread=1.0):
    """n points along a line from a at ``angle``, ``offset`` px to its left, spread px across."""
    d = np.array([np.cos(angle), np.sin(angle)])
    nl = np.array([-d[1], d[0]])
    return (np.asarray(a, float) + rng.uniform(0, length, (n, 1)) * d
            + (offset + rng.normal(0, spread, (n, 1))) * nl)


def test_carry_to_segment_puts_the_sets_line_on_the_segment():
    """A band 3 px off and 0.03 rad skewed from a segment ends with its own TLS line
    on the segment's line (geometry.lines.line_through), its count, its spread across
    the line and its extent along it unchanged."""
    from graphtrack.detect.pixel_sets import carry_to_segment
    from graphtrack.detect.ransac import fit_line_tls
    from graphtrack.geometry.lines import line_through, pixel_residual

    rng = np.random.default_rng(3)
    a, angle = np.array([40.0, 25.0]), 0.4
    seg = np.concatenate([a, a + 120.0 * np.array([np.cos(angle), np.sin(angle)])])
    pts = _band(rng, a, angle + 0.03, 3.0)
    moved = carry_to_segment(pts, seg)
    rho, theta = line_through(seg[:2], seg[2:])
    assert len(moved) == len(pts)
    r = pixel_residual(moved, rho, theta)
    assert abs(r.mean()) < 1e-9                        # the line passes through the centroid
    got = fit_line_tls(moved)
    assert abs(np.sin(got[1] - theta)) < 1e-9          # and has the segment's direction
    before = pixel_residual(pts, *fit_line_tls(pts))
    assert np.isclose(r.std(), before.std(), rtol=1e-9)   # spread across kept (rigid)
    d = np.array([np.cos(angle), np.sin(angle)])
    assert np.isclose(np.ptp(moved @ d), np.ptp(pts @ d), rtol=0.01)


def test_carry_to_segment_leaves_sets_that_are_not_a_band_along_it():
    """Too few pixels, a degenerate segment, or a set whose line is more than
    MAX_CARRY_ANGLE off the segment's: returned as it is."""
    from graphtrack.detect.pixel_sets import MAX_CARRY_ANGLE, carry_to_segment

    rng = np.random.default_rng(4)
    seg = np.array([0.0, 0.0, 100.0, 0.0])
    skew = _band(rng, (0.0, 0.0), 2 * MAX_CARRY_ANGLE, 1.0)
    np.testing.assert_array_equal(carry_to_segment(skew, seg), skew)
    np.testing.assert_array_equal(carry_to_segment(skew[:1], seg), skew[:1])
    np.testing.assert_array_equal(carry_to_segment(skew, np.array([5.0, 5.0, 5.0, 5.0])), skew)
    blob = rng.normal(0.0, 2.0, (300, 2)) + (50.0, 1.0)          # no direction to carry
    for seg_b in (seg, np.array([50.0, -50.0, 50.0, 50.0])):
        np.testing.assert_array_equal(carry_to_segment(blob, seg_b), blob)
    nan = skew.copy()
    nan[3] = np.nan
    np.testing.assert_array_equal(carry_to_segment(nan, seg), nan)


@pytest.mark.parametrize("angle", [np.pi / 2, -np.pi / 2 + 0.01, 0.0, 2.5])
@pytest.mark.parametrize("skew", [0.04, -0.04])
def test_carry_to_segment_any_orientation(angle, skew):
    """Vertical, horizontal and steep segments, skewed either way, ends swapped:
    the carried set's centroid is on the segment's line and its TLS line parallel."""
    from graphtrack.detect.pixel_sets import carry_to_segment
    from graphtrack.detect.ransac import fit_line_tls
    from graphtrack.geometry.lines import line_through, pixel_residual

    rng = np.random.default_rng(5)
    a = np.array([200.0, 150.0])
    b = a + 80.0 * np.array([np.cos(angle), np.sin(angle)])
    pts = _band(rng, a, angle + skew, -2.0, length=80.0)
    rho, theta = line_through(a, b)
    for seg in (np.concatenate([a, b]), np.concatenate([b, a])):
        moved = carry_to_segment(pts, seg)
        assert abs(pixel_residual(moved, rho, theta).mean()) < 1e-9
        assert abs(np.sin(fit_line_tls(moved)[1] - theta)) < 1e-9
