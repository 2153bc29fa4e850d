"""The shaft-end factor: its residual by hand, its Jacobian against central differences on
Pose3.retract (left and right cameras), and the particle filter's batched projection of the
same point against it."""
import gtsam
import numpy as np
import pytest

from factors.shaft_end import ShaftEndError, shaft_end_factor
from graphtrack.estimate import observation_models as om
from graphtrack.detect.base import Observation
from graphtrack.estimate.pf.projection import frame_geometry, project
from graphtrack.geometry.se3 import bw_to_matrix
from graphtrack.geometry.shaft_end import front_point
from graphtrack.robot.features import base_features
from graphtrack.sim.synthetic import sequence


@pytest.fixture(scope="module")
def scene():
    robot, cam, E0, fr = sequence(2, seed=3)
    f = fr[1]
    F = base_features(robot, f.q)
    sf = robot.shaft_features[0]
    assert sf.end is not None
    centre = F.shaft_end[0]
    return robot, cam, E0, f, F, centre


def _end_pixel(E, centre, axis, r, K):
    c = E[:3, :3] @ centre + E[:3, 3]
    P = front_point(c, E[:3, :3] @ axis, r) @ K.T
    return P[:2] / P[2]


def _error(scene, shift=(0.0, 0.0), kernel="none", sigma=2.0):
    robot, cam, E0, f, F, centre = scene
    p = _end_pixel(f.E_true, centre, F.shaft_d[0], F.shaft_r[0], cam.K)
    p_dir = _end_pixel(f.E_true, centre - 0.01 * F.shaft_d[0], F.shaft_d[0], F.shaft_r[0], cam.K)
    d = (p - p_dir) / np.linalg.norm(p - p_dir)
    det = p + shift[0] * d + shift[1] * np.array([-d[1], d[0]])
    return ShaftEndError(det, d, centre, F.shaft_d[0], F.shaft_r[0], cam.K, sigma, kernel)


def test_residual_is_the_offset_along_the_shaft(scene):
    E = scene[3].E_true
    assert abs(_error(scene).evaluate(E, False)[0][0]) < 1e-9
    # 3 px towards the wrist: the prediction is 3 px short of it, z = -3 / sigma
    assert _error(scene, (3.0, 0.0)).evaluate(E, False)[0][0] == pytest.approx(-1.5, abs=1e-9)
    # across the shaft: the lines' business, not this factor's
    assert abs(_error(scene, (0.0, 5.0)).evaluate(E, False)[0][0]) < 1e-9


def _at(fn, E):
    """The observing camera's pose: C . E through another camera, E itself for the left."""
    return E if fn.extrinsic is None else fn.extrinsic @ E


def _numerical(fn, pose, h=1e-7):
    cols = []
    for k in range(6):
        x = np.zeros(6)
        x[k] = h
        cols.append((fn(pose.retract(x)) - fn(pose.retract(-x))) / (2 * h))
    return np.stack(cols, -1)


@pytest.mark.parametrize("kernel", ["none", "huber", "cauchy"])
@pytest.mark.parametrize("stereo", [False, True])
def test_jacobian_matches_central_differences(scene, kernel, stereo):
    robot, cam, E0, f, F, centre = scene
    fn = _error(scene, (4.0, 1.0), kernel)
    if stereo:   # through another camera C: the error at C . E, the Jacobian unchanged in form
        fn.extrinsic = bw_to_matrix(np.array([-0.005, 0.0002, 0.0001, 0.0, 0.01, 0.002]))
    pose = gtsam.Pose3(f.E_true).retract(np.array([1e-3, -5e-4, 2e-4, 5e-4, 1e-4, -2e-4]))
    _, J = fn.evaluate(_at(fn, pose.matrix()), True)
    num = _numerical(lambda P: fn.evaluate(_at(fn, P.matrix()), False)[0], pose)
    np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-6)
    # the gtsam.CustomFactor around it linearises to the same Jacobian
    key = gtsam.symbol("x", 0)
    fac = shaft_end_factor(key, fn.p, fn.d, fn.c_b, fn.a_b, fn.r, cam.K, fn.sigma, kernel, fn.extrinsic)
    v = gtsam.Values()
    v.insert(key, pose)
    np.testing.assert_allclose(fac.linearize(v).jacobian()[0], J, rtol=1e-9, atol=1e-12)


def test_particle_filter_projection_and_term_agree_with_the_factor(scene):
    robot, cam, E0, f, F, centre = scene
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(0, 0.003, (5, 3)), rng.normal(0, 0.02, (5, 3))], 1)
    h = project(frame_geometry(robot, f.q, E0), cam.K, x)
    fn = _error(scene)
    obs = Observation("line-intensities", shaft_end=np.concatenate([fn.p, fn.d])[None])
    ll = om.shaft_end_loglik(h.end_u, h.end_v, obs, sigma=2.0, outlier_sigmas=3.0)
    for n in range(5):
        E = bw_to_matrix(x[n]) @ E0
        assert np.allclose([h.end_u[n], h.end_v[n]], _end_pixel(E, centre, F.shaft_d[0], F.shaft_r[0], cam.K))
        z = fn.evaluate(E, False)[0][0]
        assert ll[n] == pytest.approx(max(-0.5 * z * z, -4.5))
    # no detected end: no term
    assert om.shaft_end_loglik(h.end_u, h.end_v, Observation("line-intensities")) == 0.0


@pytest.mark.parametrize("kernel", ["none", "huber"])
def test_end_offset_state(scene, kernel):
    """On (E, b): z = (d . (pi(P) - p) + e) / sigma with e = b[END_OFFSET], the detected end
    p = pi(P) + e d; the Jacobian against central differences in E and b, and the
    gtsam.CustomFactor on both keys linearises to it."""
    from factors.edge_bias import BIAS_DIM, END_OFFSET, bias_key
    from test_factors_edge_bias import _central_differences

    robot, cam, E0, f, F, centre = scene
    E = f.E_true
    fn = _error(scene, (3.0, 0.0), kernel)        # detected 3 px towards the wrist
    fn.on_bias = True
    b = np.zeros(BIAS_DIM)
    b[END_OFFSET] = 3.0                            # the state explains the offset
    assert abs(fn.evaluate(E, False, b)[0][0]) < 1e-9
    b[END_OFFSET] = 1.0
    if kernel == "none":
        assert fn.evaluate(E, False, b)[0][0] == pytest.approx(-1.0, abs=1e-9)   # (-3 + 1) / 2
    b = np.array([0.3, -0.2, 0.5, 0.1, 1.2])
    pose = gtsam.Pose3(E).retract(np.array([1e-3, -5e-4, 2e-4, 5e-4, 1e-4, -2e-4]))
    _, J = fn.evaluate(pose.matrix(), True, b)
    assert J.shape == (1, 6 + BIAS_DIM)
    num = _central_differences(fn, pose, b)
    np.testing.assert_allclose(J[:, :6], num[:, :6], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(J[:, 6:], num[:, 6:], rtol=0.0, atol=1e-6)
    x, bk = gtsam.symbol("x", 0), bias_key(0)
    fac = shaft_end_factor(x, fn.p, fn.d, fn.c_b, fn.a_b, fn.r, cam.K, fn.sigma, kernel, None, bk)
    assert list(fac.keys()) == [x, bk]
    v = gtsam.Values()
    v.insert(x, pose)
    v.insert(bk, b)
    gf = fac.linearize(v)
    np.testing.assert_allclose(gf.jacobian()[0], J, rtol=1e-9, atol=1e-12)
