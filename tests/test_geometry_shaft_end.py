"""The shaft end's visible point against a brute-force search of the rim, and its Jacobian
against central differences."""
import numpy as np
import pytest

from graphtrack.geometry.shaft_end import front_point, front_point_jacobian

K = np.array([[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]])


def _project(X):
    p = X @ K.T
    return p[..., :2] / p[..., 2:]


def _brute_force(c, a, r, n=200000):
    """The rim point seen on the image of the axis, nearer the camera: the rim circle
    sampled densely, the samples whose image lies on the axis's image, the nearest."""
    e1 = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rim = c + r * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    p0, p1 = _project(c), _project(c + 0.02 * a)
    d = (p1 - p0) / np.linalg.norm(p1 - p0)
    off = np.abs((_project(rim) - p0) @ np.array([-d[1], d[0]]))
    on_axis = rim[off < np.sort(off)[40]]
    return on_axis[np.argmin(np.linalg.norm(on_axis, axis=1))]


@pytest.mark.parametrize("seed", range(4))
def test_front_point_is_the_rim_point_seen_along_the_axis(seed):
    rng = np.random.default_rng(seed)
    c = np.array([rng.uniform(-0.02, 0.02), rng.uniform(-0.02, 0.02), rng.uniform(0.08, 0.15)])
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    P = front_point(c, a, 0.004)
    assert np.linalg.norm(P - c) == pytest.approx(0.004)
    assert abs((P - c) @ a) < 1e-12
    # the brute force's samples are 2 pi r / n apart: agreement to a few of them
    assert np.linalg.norm(P - _brute_force(c, a, 0.004)) < 2e-6
    # and it is not the centre's image: the offset along the axis's image is what the module doc says
    assert np.linalg.norm(_project(P) - _project(c)) > 0.1


def test_front_point_batches_and_degenerates_to_the_centre():
    rng = np.random.default_rng(5)
    c = rng.normal(size=(4, 3)) * 0.02 + [0, 0, 0.1]
    a = rng.normal(size=(4, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    P = front_point(c, a, 0.004)
    for i in range(4):
        assert np.allclose(P[i], front_point(c[i], a[i], 0.004))
    c0 = np.array([0, 0, 0.1])
    assert np.allclose(front_point(c0, np.array([0, 0, 1.0]), 0.004), c0)   # looking down the axis


def test_front_point_jacobian_matches_central_differences():
    rng = np.random.default_rng(2)
    c = np.array([0.01, -0.005, 0.11])
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    P, dc, da = front_point_jacobian(c, a, 0.004)
    assert np.allclose(P, front_point(c, a, 0.004))
    h = 1e-7
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        num_c = (front_point(c + e, a, 0.004) - front_point(c - e, a, 0.004)) / (2 * h)
        num_a = (front_point(c, a + e, 0.004) - front_point(c, a - e, 0.004)) / (2 * h)
        assert np.allclose(dc[:, k], num_c, atol=1e-6)
        assert np.allclose(da[:, k], num_a, atol=1e-6)
