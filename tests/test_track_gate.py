"""The detector's association gate widens with the estimate's uncertainty (Pipeline.gate)."""
import numpy as np
import pytest

from graphtrack.sim.synthetic import Q0, make_scene
from graphtrack.io.frame import Frame
from graphtrack.io.context import TrackingContext
from graphtrack.detect.options import DetectionOptions
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.track import MAX_GATE_PX, Pipeline, TrackOptions

CANNY = DetectionOptions(detector="canny")


@pytest.fixture(scope="module")
def pipe():
    robot, cam, E0 = make_scene()
    return Pipeline(TrackingContext(robot, cam, E0), TrackOptions(estimator="smoother", detection=CANNY))


def test_gate_follows_the_estimate_std(pipe):
    frame = Frame(0, 0.0, None, Q0[:6], Q0[6])
    base = pipe.detector.association.max_offset
    sc = pipe.scale                                        # gates are in detection pixels
    pipe.last_std = None                                   # before the first estimate: widest
    assert pipe.gate(frame).max_offset == pytest.approx(MAX_GATE_PX * sc)
    pipe.last_std = np.full(6, 1e-6)                       # converged: the configured gate
    assert pipe.gate(frame) is None
    pipe.last_std = np.full(6, np.nan)                     # no covariance: the configured gate
    assert pipe.gate(frame) is None
    # 2 mm sideways (x and y): 3 f |(2, 2)| mm / Z, Z the shaft point's depth (hand-computed)
    pipe.last_std = np.array([2e-3, 2e-3, 0, 0, 0, 0])
    from graphtrack.robot.kinematics import link_transforms

    sf = pipe.ctx.robot.shaft_features[0]
    T = pipe.ctx.handeye @ link_transforms(pipe.ctx.robot, Q0)[sf.link]
    z = (T @ np.r_[sf.position, 1.0])[2]
    want = 3 * sc * pipe.ctx.camera.K[0, 0] * np.sqrt(2) * 2e-3 / z
    assert want > base
    assert pipe.gate(frame).max_offset == pytest.approx(want, rel=1e-9)
    # and the same through a rotation about the camera's x axis: 3 f |w|
    pipe.last_std = np.array([0, 0, 0, 0.02, 0, 0])
    assert pipe.gate(frame).max_offset == pytest.approx(sc * min(3 * pipe.ctx.camera.K[0, 0] * 0.02, MAX_GATE_PX))


def test_marker_gates_are_in_detection_pixels():
    """At a detection scale s the estimators' marker gates become gate / s full-size px."""
    import gtsam

    from graphtrack.detect.base import Observation
    from graphtrack.estimate import observation_models as om
    from graphtrack.estimate.graph import FactorOptions, frame_factors, key
    from graphtrack.robot.features import base_features

    robot, cam, E0 = make_scene()
    ctx = TrackingContext(robot, cam, E0)
    half = Pipeline(ctx, TrackOptions(estimator="smoother", detection=DetectionOptions(detector="canny", scale=0.5)))
    assert half.estimator.fopts.gate_scale == 2.0
    pf = Pipeline(ctx, TrackOptions(estimator="pf", detection=DetectionOptions(detector="canny", scale=0.5),
                                    estimation=EstimatorOptions(particles=16)))
    assert pf.estimator.marker_gate == pytest.approx(2.0 * om.MARKER_GATE)
    full = Pipeline(ctx, TrackOptions(estimator="smoother", detection=DetectionOptions(detector="canny", scale=1.0)))
    assert full.estimator.fopts.gate_scale == 1.0

    # a marker detected 90 px from its prediction: outside a 60 px gate, inside 60 * 2
    q = np.asarray(Q0, float)
    uv = cam.project_undistorted(base_features(robot, q).transformed(E0).points)
    obs = Observation(model="line-intensities", markers=uv[:1] + np.array([90.0, 0.0]))
    values = gtsam.Values()
    values.insert(key(0), gtsam.Pose3(E0))
    for scale, associated in ((1.0, False), (2.0, True)):
        (f,) = frame_factors(0, q, obs, robot, cam.K, FactorOptions(gate_scale=scale))
        assert (f.error(values) > 0) == associated


def test_batch_gates_its_detector_like_the_smoother():
    """The batch's provisional rows are the online smoother's, std included, so the
    detector it runs behind is gated exactly as the smoother's (same detections);
    without the std every frame had the widest gate, 150 px."""
    from graphtrack.sim.synthetic import sequence
    from graphtrack.detect.base import Observation

    robot, cam, E0, frames = sequence(5, seed=3)
    ctx = TrackingContext(robot, cam, E0)
    smoother = Pipeline(ctx, TrackOptions(estimator="smoother", detection=CANNY, observation="canny"))
    batch = Pipeline(ctx, TrackOptions(estimator="batch", detection=CANNY, observation="canny"))
    for f in frames:
        frame = Frame(f.index, f.stamp, None, f.q[:6], f.q[6])
        obs = Observation("canny", lines=f.lines, markers=f.markers)
        a = smoother.estimator.step(frame, obs)
        b = batch.estimator.step(frame, obs)
        smoother.last_std, batch.last_std = a.std, b.std
        assert b.std is not None and np.allclose(a.std, b.std) and np.allclose(a.E, b.E)
        ga, gb = smoother.gate(frame), batch.gate(frame)
        assert (ga is None) == (gb is None)
        assert ga is None or ga.max_offset == pytest.approx(gb.max_offset)


def test_gate_along_matches_a_monte_carlo_spread():
    """gate_along's sigma is the spread along d of the projected point under sampled left
    corrections (b, w) (exact rotations, pinhole projection): the oracle."""
    from graphtrack.estimate.gating import gate_along
    from graphtrack.geometry.se3 import so3_exp_batch

    K = np.array([[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]])
    X = np.array([0.01, -0.02, 0.12])
    rng = np.random.default_rng(0)
    A = rng.standard_normal((6, 6)) * np.r_[[1e-3] * 3, [1e-2] * 3][:, None]
    cov = A @ A.T
    d = np.array([0.6, 0.8])
    s = rng.multivariate_normal(np.zeros(6), cov, 40000)
    R = so3_exp_batch(s[:, 3:])                    # (3, 3, N)
    Y = np.einsum("ijn,j->ni", R, X) + s[:, :3]
    uv = Y[:, :2] / Y[:, 2:] * 800.0
    spread = np.std(uv @ d)
    g = gate_along(X, d, K, cov, sigma=0.0, floor=0.0)
    assert g / 3.0 == pytest.approx(spread, rel=0.05)
    assert gate_along(X, d, K, cov, sigma=0.0, floor=1e4) == 1e4          # never below the floor
    assert gate_along(np.array([0.01, 0.0, -0.1]), d, K, cov, sigma=1.0, floor=5.0) == np.inf   # behind the camera
    assert gate_along(X, d, K, np.zeros((6, 6)), sigma=2.0, floor=0.0) == pytest.approx(6.0)


def test_end_gate_follows_the_slide_along_the_shaft(pipe):
    """The shaft end's gate: inf before the first estimate; the floor when confident; for a
    2 mm slide along the shaft's axis, 3 x the end's image displacement along the shaft
    (a finite difference of the projection, hand-built) with the detection noise."""
    from graphtrack.estimate.observation_models import END_SIGMA
    from graphtrack.geometry.shaft_end import end_pixel
    from graphtrack.robot.features import base_features
    from graphtrack.track.pipeline import END_GATE_MIN_PX

    frame = Frame(0, 0.0, None, Q0[:6], Q0[6])
    pipe.last_E, pipe.last_cov = pipe.ctx.handeye.copy(), None
    assert pipe.end_gate(frame, pipe.predicted_end(frame)) == np.inf
    pipe.last_cov = np.eye(6) * 1e-14
    assert pipe.end_gate(frame, pipe.predicted_end(frame)) == pytest.approx(END_GATE_MIN_PX)
    F = base_features(pipe.ctx.robot, Q0).transformed(pipe.ctx.handeye)
    a, r, K = F.shaft_d[0], pipe.ctx.robot.shaft_features[0].radius, pipe.ctx.camera.K
    pipe.last_cov = np.zeros((6, 6))
    pipe.last_cov[:3, :3] = (2e-3) ** 2 * np.outer(a, a)
    p0, d = end_pixel(F.shaft_end[0], a, r, K)
    p1, _ = end_pixel(F.shaft_end[0] + 1e-6 * a, a, r, K)
    along = d @ (p1 - p0) / 1e-6 * 2e-3                                 # px per 2 mm
    assert 3.0 * along > END_GATE_MIN_PX
    assert pipe.end_gate(frame, pipe.predicted_end(frame)) == pytest.approx(3.0 * np.hypot(along, END_SIGMA), rel=1e-3)
