"""graphtrack.geometry.pinhole against OpenCV's projection and central differences."""
import cv2
import numpy as np

from graphtrack.geometry import pinhole

K = np.array([[1010.0, 0.0, 478.5], [0.0, 995.0, 271.25], [0.0, 0.0, 1.0]])


def _points(n=50, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.04, 0.04, n), rng.uniform(-0.03, 0.03, n), rng.uniform(0.05, 0.2, n)])


def test_project_matches_opencv():
    P = _points()
    cv, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, np.zeros(5))
    np.testing.assert_allclose(pinhole.project(K, P), cv[:, 0], atol=1e-9)
    # any leading shape, and the components' form
    np.testing.assert_allclose(pinhole.project(K, P.reshape(5, 10, 3)), cv[:, 0].reshape(5, 10, 2), atol=1e-9)
    u, v = pinhole.pixels(K, *P.T)
    np.testing.assert_allclose(np.column_stack([u, v]), cv[:, 0], atol=1e-9)


def test_jacobian_matches_central_differences():
    P = _points(20, seed=1)
    J = pinhole.jacobian(K, P)
    h = 1e-7
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        num = (pinhole.project(K, P + d) - pinhole.project(K, P - d)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], num, rtol=1e-6, atol=1e-3)


def test_points_behind_the_camera():
    P = np.array([[0.01, 0.0, 0.1], [0.01, 0.0, 0.0], [0.01, 0.0, -0.1]])
    uv = pinhole.project(K, P)
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1:]))
    J = pinhole.jacobian(K, P)
    assert np.all(np.isnan(J[1:, 0, [0, 2]])) and np.all(np.isnan(J[1:, 1, [1, 2]]))
    # a finite stand-in keeps the arithmetic finite; the point in front is unchanged
    uv1 = pinhole.project(K, P, behind=1.0)
    assert np.all(np.isfinite(uv1)) and np.array_equal(uv1[0], uv[0])
    np.testing.assert_allclose(uv1[2], [K[0, 0] * 0.01 + K[0, 2], K[1, 2]])
