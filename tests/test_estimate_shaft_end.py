"""The online estimators with the shaft-end observation: a hand-eye error that slides the tool
along its shaft, which the two silhouette lines do not see, is resolved by the end."""
import numpy as np
import pytest

from graphtrack.estimate import make_estimator
from graphtrack.geometry.se3 import bw_to_matrix
from graphtrack.io.frame import Frame
from graphtrack.robot.features import base_features
from graphtrack.sim.synthetic import Q0, joint_trajectory, make_scene, observe

N = 20
SLIDE = 0.006    # m along the shaft


def _track(estimator: str, with_end: bool, seed: int = 0) -> np.ndarray:
    """The tip's image error (px) of each frame's estimate. The true E is the nominal one
    slid SLIDE along the shaft (camera frame, at the start pose); markers are not used."""
    scene = make_scene()
    F = base_features(scene.robot, Q0).transformed(scene.E0)
    E_true = bw_to_matrix(np.concatenate([SLIDE * F.shaft_d[0], np.zeros(3)])) @ scene.E0
    rng = np.random.default_rng(seed)
    est = make_estimator(estimator, scene.ctx, seed=seed) if estimator == "pf" else make_estimator(estimator, scene.ctx)
    err = []
    for k, q in enumerate(joint_trajectory(N)):
        f = observe(scene, q, E_true, rng, index=k, stamp=k / 30.0, pixel_noise=1.0,
                    shaft_end_noise=1.0 if with_end else None)
        e = est.step(Frame(k, k / 30.0, None, q[:6], q[6]), f.observation(markers=False))
        tip = np.append(base_features(scene.robot, q).tip, 1.0)
        uv = scene.camera.project_undistorted(np.stack([(e.E @ tip)[:3], (E_true @ tip)[:3]]))
        err.append(np.linalg.norm(uv[0] - uv[1]))
    return np.array(err)


@pytest.mark.parametrize("estimator", ["pf", "smoother"])
def test_the_shaft_end_resolves_a_slide_along_the_shaft(estimator):
    with_end, without = _track(estimator, True), _track(estimator, False)
    # 6 mm is ~45 px at the tip here: the lines alone leave most of it, the end takes it out
    # (what is left without markers is the roll about the shaft and the depth)
    assert np.all(without[-5:] > 25.0)
    assert np.all(with_end[-5:] < 6.0)
