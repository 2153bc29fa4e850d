"""SE(3) / (b, w) parameterisation against scipy and gtsam as independent oracles."""
import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphtrack.geometry import se3


def random_rotvecs(n, rng, max_angle=np.pi):
    w = rng.normal(size=(n, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True) * rng.uniform(0, max_angle, (n, 1))


def test_exp_matches_scipy():
    rng = np.random.default_rng(0)
    w = random_rotvecs(500, rng)
    np.testing.assert_allclose(se3.so3_exp(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-14)


def test_zero_and_tiny_angles_have_no_nan():
    w = np.array([[0.0, 0, 0], [1e-12, 0, 0], [0, 1e-7, -1e-7], [3e-5, 2e-5, 0]])
    R = se3.so3_exp(w)
    assert np.all(np.isfinite(R))
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-15)
    back = se3.so3_log(R)
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(back, w, atol=1e-15)


def test_log_near_pi():
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for eps in (0.0, 1e-9, 1e-6, 1e-4, 1e-2):
        w = axes * (np.pi - eps)
        R = Rotation.from_rotvec(w).as_matrix()
        w2 = se3.so3_log(R)
        assert np.all(np.isfinite(w2))
        np.testing.assert_allclose(np.linalg.norm(w2, axis=1), np.pi - eps, atol=1e-7)
        np.testing.assert_allclose(se3.so3_exp(w2), R, atol=1e-7)


def test_bw_roundtrip_and_vectorised_shapes():
    rng = np.random.default_rng(2)
    bw = np.concatenate([rng.normal(size=(4, 5, 3)) * 0.01, random_rotvecs(20, rng).reshape(4, 5, 3)], -1)
    T = se3.bw_to_matrix(bw)
    assert T.shape == (4, 5, 4, 4)
    np.testing.assert_allclose(se3.matrix_to_bw(T), bw, atol=1e-10)


def test_pose3_roundtrip_matches_gtsam():
    rng = np.random.default_rng(3)
    for bw in np.concatenate([rng.normal(size=(20, 3)), random_rotvecs(20, rng)], 1):
        T = se3.bw_to_matrix(bw)
        p = se3.to_pose3(T)
        np.testing.assert_allclose(p.rotation().matrix(), gtsam.Rot3.Rodrigues(bw[3:]).matrix(), atol=1e-12)
        np.testing.assert_allclose(p.translation(), bw[:3], atol=1e-14)
        np.testing.assert_allclose(se3.from_pose3(p), T, atol=1e-14)


def test_quaternion_convention_xyzw():
    rng = np.random.default_rng(4)
    w = random_rotvecs(300, rng)
    R = Rotation.from_rotvec(w).as_matrix()
    q = se3.matrix_to_quaternion(R)
    ref = Rotation.from_rotvec(w).as_quat()  # scipy: (x, y, z, w)
    ref = np.where(ref[:, 3:4] < 0, -ref, ref)
    np.testing.assert_allclose(q, ref, atol=1e-8)
    np.testing.assert_allclose(se3.quaternion_to_matrix(q), R, atol=1e-12)


def test_invert_and_transform_points():
    rng = np.random.default_rng(5)
    T = se3.bw_to_matrix(np.concatenate([rng.normal(size=(10, 3)), random_rotvecs(10, rng)], 1))
    np.testing.assert_allclose(se3.invert(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)
    p = rng.normal(size=(10, 3))
    ref = np.einsum("nij,nj->ni", T, np.concatenate([p, np.ones((10, 1))], 1))[:, :3]
    np.testing.assert_allclose(se3.transform_points(T, p), ref, atol=1e-12)


@pytest.mark.parametrize("spread", [0.01, 0.3])
def test_average_rotations_recovers_mean(spread):
    rng = np.random.default_rng(6)
    R0 = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    noise = Rotation.from_rotvec(rng.normal(size=(4000, 3)) * spread).as_matrix()
    Ravg = se3.average_rotations(R0 @ noise)
    assert np.linalg.norm(se3.so3_log(Ravg.T @ R0)) < 3 * spread / np.sqrt(4000) * 3
    assert abs(np.linalg.det(Ravg) - 1) < 1e-12


def _axis_angles(rng, n: int = 400) -> np.ndarray:
    """Rows across the branches: zero, below and above the series' t^2 = 1e-8, generic, near pi, beyond."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-12, 9.9e-5, 1.01e-4, np.pi - 1e-9, np.pi, 2.5 * np.pi],
                             10.0 ** rng.uniform(-7, 0.5, n - 7)])
    return axes * angles[:, None]


def test_so3_exp_batch_matches_the_single_form_and_scipy():
    w = _axis_angles(np.random.default_rng(3))
    R = se3.so3_exp_batch(w)
    assert R.shape == (3, 3, len(w)) and np.all(np.isfinite(R))
    single = np.stack([se3.so3_exp(v) for v in w])           # (N, 3, 3)
    np.testing.assert_allclose(np.moveaxis(R, -1, 0), single, atol=1e-15, rtol=0)
    np.testing.assert_allclose(np.moveaxis(R, -1, 0), Rotation.from_rotvec(w).as_matrix(), atol=1e-14, rtol=0)
    assert se3.so3_exp_batch(np.zeros(3)).shape == (3, 3, 1)
    np.testing.assert_array_equal(se3.so3_exp_batch(np.zeros((2, 3))), np.broadcast_to(np.eye(3)[..., None], (3, 3, 2)))
