"""The detector's association gate widens with the estimate's uncertainty (Pipeline.gate)."""
import numpy as np
import pytest

from factors.synthetic import Q0, make_scene
from graphtrack.estimate.base import Frame
from graphtrack.estimate.context import TrackingContext
from graphtrack.track import MAX_GATE_PX, Pipeline, TrackOptions


@pytest.fixture(scope="module")
def pipe():
    robot, cam, E0 = make_scene()
    return Pipeline(TrackingContext(robot, cam, E0), TrackOptions(estimator="smoother", detector="canny"))


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
