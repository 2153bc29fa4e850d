"""The synthetic world (graphtrack.sim.synthetic): exact observations of every model."""
import cv2
import numpy as np
import pytest

from graphtrack.geometry.se3 import bw_to_matrix, matrix_to_bw
from graphtrack.robot.features import base_features
from graphtrack.sim.synthetic import (HANDEYE_ERROR, joint_trajectory, make_scene, observe, pose_error,
                                      random_handeye_error, sequence)

SCENE = make_scene()


def test_noise_free_observations_are_exact():
    """Pixels lie on their own limb's (rho, theta) line; point markers are OpenCV's
    projection of the marker points through E; disc markers differ from them by the
    disc's centroid offset only (less than the disc's image radius); every observation inside the image."""
    q = joint_trajectory(1)[0]
    E = SCENE.true_E()
    f = observe(SCENE, q, E, np.random.default_rng(0), pixel_noise=0.0, marker_model="point")
    assert f.valid and len(f.pixels) == 2 and all(len(p) > 200 for p in f.pixels)
    for i, px in enumerate(f.pixels):
        rho, th = f.lines[i]
        r = px @ np.array([np.cos(th), np.sin(th)]) - rho
        assert np.abs(r).max() < 1e-6
        assert np.all((px >= 0) & (px < [SCENE.camera.width, SCENE.camera.height]))
    P = base_features(SCENE.robot, q).transformed(E).points
    uv, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), SCENE.camera.K, None)
    uv = uv.reshape(-1, 2)
    assert len(f.markers) >= 1
    d = np.linalg.norm(uv[:, None] - f.markers[None], axis=-1).min(0)
    assert d.max() < 1e-9
    disc = observe(SCENE, q, E, np.random.default_rng(0), pixel_noise=0.0).markers
    radius = max(p.radius for p in SCENE.robot.point_features)            # m
    image_radius = radius * SCENE.camera.K[0, 0] / P[:, 2].min()           # px, the disc's image
    gap = np.linalg.norm(disc - f.markers, axis=1)
    assert disc.shape == f.markers.shape and np.all(gap > 0) and np.all(gap < image_radius)
    with pytest.raises(ValueError):
        observe(SCENE, q, E, np.random.default_rng(0), marker_model="blob")


def test_sequence_truth_seed_and_walk():
    a = sequence(5, seed=2, pixel_noise=1.0, marker_noise=1.0)
    b = sequence(5, seed=2, pixel_noise=1.0, marker_noise=1.0)
    for fa, fb in zip(a.frames, b.frames):
        assert all(np.array_equal(x, y) for x, y in zip(fa.pixels, fb.pixels))
        np.testing.assert_array_equal(fa.markers, fb.markers)
    np.testing.assert_allclose(matrix_to_bw(a.frames[0].E_true @ np.linalg.inv(a.E0)), HANDEYE_ERROR, atol=1e-12)
    assert all(np.array_equal(f.E_true, a.frames[0].E_true) for f in a.frames)     # no walk
    assert [f.index for f in a.frames] == list(range(5)) and a.frames[3].stamp == pytest.approx(0.1)
    w = sequence(400, seed=2, walk_sigma=(1e-4, 1e-3), pixels_per_edge=2)   # std of std ~ 3.5 %
    steps = np.array([matrix_to_bw(g.E_true @ np.linalg.inv(f.E_true)) for f, g in zip(w.frames, w.frames[1:])])
    np.testing.assert_allclose(steps.std(0), [1e-4] * 3 + [1e-3] * 3, rtol=0.15)
    fr = a.frames[1].frame()
    np.testing.assert_array_equal(fr.q, a.frames[1].q)          # DH joints + jaw
    polar = a.frames[1].observation("line-intensities-polar")
    assert polar.lines.shape == (2, 2) and len(polar.pixels) == 0
    assert len(a.frames[1].observation("canny", markers=False).markers) == 0


def test_pose_error_and_random_handeye_error():
    x = random_handeye_error(np.random.default_rng(0), 3.0, 2.0)
    mm, deg = pose_error(bw_to_matrix(x) @ SCENE.E0, SCENE.E0)
    assert mm == pytest.approx(3.0) and deg == pytest.approx(2.0)
