"""graphtrack.geometry.image_scale against cv2.resize and hand-computed values."""
import cv2
import numpy as np

from graphtrack.geometry.image_scale import scale_lines, scale_points


def test_points_follow_cv2_resize():
    # a single bright pixel's centre, resized by 4 with INTER_LINEAR: the blob's centroid
    img = np.zeros((20, 30), np.float32)
    img[7, 11] = 1.0
    big = cv2.resize(img, (120, 80), interpolation=cv2.INTER_LINEAR)
    ys, xs = np.nonzero(big)
    w = big[ys, xs]
    centroid = [np.sum(w * xs) / w.sum(), np.sum(w * ys) / w.sum()]
    np.testing.assert_allclose(scale_points([11.0, 7.0], 4.0), centroid, atol=1e-3)


def test_points_and_segments_hand_computed():
    np.testing.assert_allclose(scale_points([[0.0, 0.0], [9.5, 3.0]], 2.0, 0.5), [[0.5, -0.25], [19.5, 1.25]])
    seg = np.array([[0.0, 0.0, 9.5, 3.0]])
    np.testing.assert_allclose(scale_points(seg, 2.0, 0.5), [[0.5, -0.25, 19.5, 1.25]])
    np.testing.assert_allclose(scale_points(scale_points(seg, 4.0), 0.25), seg)


def test_lines_keep_the_scaled_points_on_them():
    rng = np.random.default_rng(0)
    lines = np.column_stack([rng.uniform(-50, 300, 8), rng.uniform(-np.pi / 2, np.pi, 8)])
    c, s = np.cos(lines[:, 1]), np.sin(lines[:, 1])
    p = lines[:, :1] * np.column_stack([c, s]) + rng.uniform(-40, 40, (8, 1)) * np.column_stack([-s, c])
    for k in (0.25, 2.0):
        L = scale_lines(lines, k)
        q = scale_points(p, k)
        np.testing.assert_allclose(L[:, 1], lines[:, 1])
        np.testing.assert_allclose(np.cos(L[:, 1]) * q[:, 0] + np.sin(L[:, 1]) * q[:, 1], L[:, 0], atol=1e-9)
