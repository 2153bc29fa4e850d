"""The occluders' visible shaft (graphtrack/sim/occluders.py)."""
import numpy as np

from graphtrack.geometry.camera import Camera
from graphtrack.sim.occluders import SHAFT_Z, shaft_samples

# structured-700015 (a randomized tuning recording) at frame 50: the tool retracted out of
# view, its shaft's axis passing 4 cm in front of the camera, far off to the side
K = np.array([[1418.74, 0, 475.7], [0, 1418.74, 274.0], [0, 0, 1]])
D = np.array([-0.1108, 0.00077, -0.00097, -0.00077, 0.0])


def _link4(origin, axis):
    L4 = np.eye(4)
    L4[:3, 3] = origin
    L4[:3, 2] = np.asarray(axis, float) / np.linalg.norm(axis)
    return L4


def test_a_shaft_out_of_view_has_no_visible_samples_though_the_distortion_folds_some_in():
    cam = Camera(K.copy(), D.copy(), 540, 960)
    L4 = _link4([0.045, -0.028, 0.076], [-0.741, 0.463, 0.487])
    P = L4[:3, 3] + SHAFT_Z[:, None] * L4[:3, 2]
    P = P[P[:, 2] > 0.01]
    uv = cam.project_raw(P)
    folded = (uv[:, 0] >= 0) & (uv[:, 0] <= 959) & (uv[:, 1] >= 0) & (uv[:, 1] <= 539)
    assert folded.any()                      # raw pixels inside the image: the fold-over
    assert len(shaft_samples(L4, cam)[0]) == 0


def test_a_shaft_in_view_keeps_its_samples_and_their_raw_pixels():
    cam = Camera(K.copy(), D.copy(), 540, 960)
    L4 = _link4([0.0, 0.0, 0.10], [-0.6, 0.4, 0.3])
    P, uv = shaft_samples(L4, cam)
    assert len(P) > 20
    np.testing.assert_allclose(uv, cam.project_raw(P))
    assert np.all((uv >= 0) & (uv <= [959, 539]))
