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
