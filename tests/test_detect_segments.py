"""Segment extraction from line / junction heatmaps, against segments drawn from known lines."""
import cv2
import numpy as np

from graphtrack.detect import segments
from graphtrack.detect.segments import extract_segments


def test_extract_recovers_synthetic_segment():
    L = np.zeros((135, 240), np.float32)
    a, b = (30.0, 20.0), (200.0, 110.0)
    cv2.line(L, (30, 20), (200, 110), 1.0, 2, cv2.LINE_AA)
    J = np.zeros_like(L)
    J[20, 30] = J[110, 200] = 1.0
    seg, support = extract_segments(L, J)
    assert len(seg) >= 1
    s = seg[0]
    ends = sorted([tuple(s[:2]), tuple(s[2:])])
    assert np.hypot(*np.subtract(ends[0], a)) < 1.5
    assert np.hypot(*np.subtract(ends[1], b)) < 1.5


def _ridge(L, a, b, width):
    cv2.line(L, (int(a[0] * 16), int(a[1] * 16)), (int(b[0] * 16), int(b[1] * 16)), 1.0, width,
             cv2.LINE_AA, shift=4)


def test_tls_direction_is_the_principal_eigenvector_of_the_weighted_scatter():
    # oracle: numpy's symmetric eigensolver on the weighted scatter matrix
    rng = np.random.default_rng(0)
    for k in range(20):
        a = rng.uniform(-np.pi, np.pi)
        Q = (rng.normal(size=(60, 2)) * [8.0, 0.7]) @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) + 40
        w = rng.random(60)
        c, u = segments._tls(Q, w)
        c0 = (w[:, None] * Q).sum(0) / w.sum()
        _, ev = np.linalg.eigh((w[:, None] * (Q - c0)).T @ (Q - c0))
        assert np.allclose(c, c0, atol=1e-12)
        assert min(np.abs(u - ev[:, 1]).max(), np.abs(u + ev[:, 1]).max()) < 1e-12


def test_a_thick_ridge_is_fitted_once_and_a_parallel_line_beside_it_is_kept(monkeypatch):
    # a 5-px ridge makes HoughLinesP propose several candidates along it: the ones on
    # the line already fitted are not fitted again; a second ridge 6 px beside it
    # (beyond fit_band of the first) is another line and must be kept
    L = np.zeros((135, 240), np.float32)
    _ridge(L, (20.0, 30.0), (220.0, 90.0), 5)
    _ridge(L, (20.0, 50.0), (220.0, 110.0), 1)
    fits = []
    real = segments._grow_and_fit
    monkeypatch.setattr(segments, "_grow_and_fit", lambda *a: fits.append(1) or real(*a))
    hough = cv2.HoughLinesP((L >= 0.5).astype(np.uint8), 1, np.pi / 180, 12, minLineLength=8.0, maxLineGap=4.0)
    seg, _ = extract_segments(L)
    assert len(fits) < len(hough)
    for a, b in (((20.0, 30.0), (220.0, 90.0)), ((20.0, 50.0), (220.0, 110.0))):
        n = np.array([-(b[1] - a[1]), b[0] - a[0]]) / np.hypot(b[0] - a[0], b[1] - a[1])
        on = [s for s in seg if max(abs((s[:2] - a) @ n), abs((s[2:] - a) @ n)) < 1.0]
        assert len(on) == 1 and np.hypot(*(on[0][2:] - on[0][:2])) > 150.0
