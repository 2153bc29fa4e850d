"""The particle filter's painted discs: detections moved to the discs' centres."""
import dataclasses

import numpy as np

from graphtrack.detect.base import Observation
from graphtrack.estimate.particle_filter import ParticleFilter
from graphtrack.estimate.pf.disc_offsets import DiscOffsets
from graphtrack.estimate.pf.projection import frame_geometry, project
from graphtrack.io.context import TrackingContext
from graphtrack.robot.features import base_features
from graphtrack.sim.synthetic import Scene, joint_trajectory, make_scene, observe, stereo_sequence

SCENE = make_scene()
Q = joint_trajectory(60)
X_TRUE = np.r_[0.002, -0.001, 0.001, np.radians([1.0, -0.5, 0.5])]


def _centres(q, E, camera=SCENE.camera, robot=SCENE.robot):
    """The markers' centres projected through E (undistorted px), and which face the camera
    (the synthetic world's markers: the same selection and order as its detections)."""
    F = base_features(robot, q).transformed(E)
    p0, d = F.shaft_p0[0], F.shaft_d[0]
    axis_pt = p0 + ((F.points - p0) @ d)[:, None] * d
    facing = np.sum((F.points - axis_pt) * (-F.points), axis=1) > 0
    return camera.project_undistorted(F.points), facing


def test_moved_detections_are_the_centres_projections():
    """Noise-free disc centroids seen through E, moved at E_hat = E, land on the centres'
    projections (the synthetic world computes the centroids in the camera frame; the
    filter moves discs sampled once in their links' frames); at an E_hat 1 mm and 0.5 deg
    off they land within 0.1 px of them."""
    E = SCENE.true_E(X_TRUE)
    off = SCENE.true_E(X_TRUE + np.r_[1e-3, 0.0, 0.0, 0.0, np.radians(0.5), 0.0]) @ np.linalg.inv(E)
    discs = DiscOffsets(SCENE.robot)
    moved_far = 0.0
    for t in range(0, 60, 6):
        f = observe(SCENE, Q[t], E, np.random.default_rng(t), pixel_noise=0.0)
        obs = f.observation("line-intensities", True)
        centre, facing = _centres(Q[t], E)
        assert np.abs(obs.markers - centre[facing]).max() > 0.5      # the centroids are off the centres
        at = discs.centre_equivalent(obs, Q[t], E, SCENE.camera.K, gate=20.0)
        np.testing.assert_allclose(at.markers, centre[facing], atol=1e-6)
        near = discs.centre_equivalent(obs, Q[t], off @ E, SCENE.camera.K, gate=20.0)
        moved_far = max(moved_far, np.abs(near.markers - centre[facing]).max())
    assert moved_far < 0.1, moved_far


def test_right_camera_through_its_extrinsic():
    """The filter moves each image's discs through its own camera: the right image's
    through right_T_left . E and K2 (which differ from the left's), both landing on the
    centres' projections in their image."""
    st = stereo_sequence(12, seed=4, scene=SCENE, pixel_noise=0.0)
    assert not np.allclose(st.right.K, st.camera.K)
    pf = ParticleFilter(st.ctx, particles=16, seed=0, search=False)
    for t in (0, 6, 11):
        f, g = st.frames[t], st.right_frames[t]
        left, right = pf._disc_centres(f.q, f.E_true, f.observation("line-intensities", True),
                                       g.observation("line-intensities", True))
        centre, facing = _centres(f.q, f.E_true, st.camera)
        np.testing.assert_allclose(left.markers, centre[facing], atol=1e-6)
        centre, facing = _centres(f.q, st.right_T_left @ f.E_true, st.right)
        assert np.abs(g.markers - centre[facing]).max() > 0.5
        np.testing.assert_allclose(right.markers, centre[facing], atol=1e-6)


def test_point_markers_among_discs_keep_their_detections():
    """A robot with one point marker among its discs: the point's detection pairs with
    its own marker (delta = 0) and stays, also when the discs' detections are missing and
    a wide gate would let it pair with a disc; the discs' detections land on their centres."""
    robot = dataclasses.replace(SCENE.robot, point_features=[
        dataclasses.replace(p, radius=0.0) if k == 0 else p for k, p in enumerate(SCENE.robot.point_features)])
    world = Scene(robot, SCENE.camera, SCENE.E0)
    E = SCENE.true_E(X_TRUE)
    discs = DiscOffsets(robot)
    checked = 0
    for t in range(0, 60, 6):
        obs = observe(world, Q[t], E, np.random.default_rng(t), pixel_noise=0.0).observation("line-intensities", True)
        centre, facing = _centres(Q[t], E, robot=robot)
        seen = np.flatnonzero(facing)
        if not facing[0] or len(seen) < 2:
            continue
        moved = discs.centre_equivalent(obs, Q[t], E, SCENE.camera.K, gate=1000.0)
        np.testing.assert_allclose(moved.markers, centre[seen], atol=1e-6)
        alone = dataclasses.replace(obs, markers=obs.markers[:1])     # the discs' detections missing
        moved = discs.centre_equivalent(alone, Q[t], E, SCENE.camera.K, gate=1000.0)
        np.testing.assert_allclose(moved.markers, centre[:1], atol=1e-6)
        checked += 1
    assert checked >= 3, checked


def test_unpaired_detections_and_point_markers_stay():
    """A detection farther than the gate from every disc is not moved; a robot whose
    markers are points gets its observation back unchanged."""
    E = SCENE.true_E(X_TRUE)
    f = observe(SCENE, Q[0], E, np.random.default_rng(0), pixel_noise=0.0)
    obs = f.observation("line-intensities", True)
    stray = np.array([[5.0, 5.0]])
    obs = dataclasses.replace(obs, markers=np.vstack([obs.markers, stray]))
    moved = DiscOffsets(SCENE.robot).centre_equivalent(obs, Q[0], E, SCENE.camera.K, gate=20.0)
    np.testing.assert_array_equal(moved.markers[-1], stray[0])
    assert np.abs(moved.markers[:-1] - obs.markers[:-1]).max() > 0.5
    points = dataclasses.replace(SCENE.robot, point_features=[dataclasses.replace(p, radius=0.0)
                                                              for p in SCENE.robot.point_features])
    plain = DiscOffsets(points)
    assert not plain.available
    assert plain.centre_equivalent(obs, Q[0], E, SCENE.camera.K, gate=20.0) is obs
    empty = Observation("line-intensities")
    assert DiscOffsets(SCENE.robot).centre_equivalent(empty, Q[0], E, SCENE.camera.K, gate=20.0) is empty


def test_a_point_marker_the_likelihood_does_not_see_takes_no_detection():
    """A point marker on the shaft's far side at the estimate is invisible to the
    likelihood (``project``'s visible), so it takes part in no pairing: a detection at its
    projection (a highlight, say) pairs with the nearest disc instead and moves by that
    disc's offset, as any detection within the gate would."""
    m = 1   # on the far side throughout this trajectory
    robot = dataclasses.replace(SCENE.robot, point_features=[
        dataclasses.replace(p, radius=0.0) if k == m else p for k, p in enumerate(SCENE.robot.point_features)])
    E = SCENE.true_E(X_TRUE)
    discs = DiscOffsets(robot)
    pf = ParticleFilter(TrackingContext(robot, SCENE.camera, SCENE.E0), particles=16, seed=0, search=False)
    checked = 0
    for t in range(0, 60, 5):
        centre, facing = _centres(Q[t], E, robot=robot)
        c, delta = discs.offsets(discs.link_poses(Q[t]), E, SCENE.camera.K)
        usable = [k for k in range(len(c)) if k != m and np.all(np.isfinite(delta[k]))]
        if facing[m] or not usable:
            continue
        obs = Observation("line-intensities", markers=centre[m:m + 1].copy())
        seen = np.ones(len(centre), bool)
        seen[m] = False
        kept = discs.centre_equivalent(obs, Q[t], E, SCENE.camera.K, gate=1000.0)          # all seen
        np.testing.assert_array_equal(kept.markers, centre[m:m + 1])    # paired with the point: stays
        moved = discs.centre_equivalent(obs, Q[t], E, SCENE.camera.K, gate=1000.0, seen=seen)
        k = usable[int(np.argmin(np.linalg.norm(c[usable] - centre[m], axis=1)))]
        np.testing.assert_allclose(moved.markers, centre[m:m + 1] - delta[k], atol=1e-9)
        # the filter passes the likelihood's visibility, which is the geometric facing test
        g = frame_geometry(robot, Q[t], SCENE.E0)
        visible = project(g, SCENE.camera.K, np.zeros((1, 6)), E @ np.linalg.inv(SCENE.E0)).visible[:, 0]
        np.testing.assert_array_equal(visible, facing)
        np.testing.assert_allclose(pf._disc_centres(Q[t], E, obs, None)[0].markers, moved.markers, atol=1e-12)
        checked += 1
    assert checked >= 3, checked


def test_the_filter_and_the_factors_agree_which_markers_are_painted_on_the_shaft():
    """A marker 10 % off the shaft's radius is a point for both (the filter's own rule
    took anything within 25 %), one on the shaft's surface a disc for both."""
    from graphtrack.robot.features import marker_discs
    from graphtrack.robot.kinematics import link_transforms

    robot, q, k = SCENE.robot, Q[0], 0
    feats = base_features(robot, q)
    p0, d, r = feats.shaft_p0[0], feats.shaft_d[0], float(feats.shaft_r[0])
    rad = (feats.points[k] - p0) - ((feats.points[k] - p0) @ d) * d
    moved = feats.points[k] + 0.10 * r * rad / np.linalg.norm(rad)     # 10 % farther out (base frame)
    T = np.linalg.inv(link_transforms(robot, q)[robot.point_features[k].link])
    marker = dataclasses.replace(robot.point_features[k], position=tuple(T[:3, :3] @ moved + T[:3, 3]))
    off = dataclasses.replace(robot, point_features=[marker] + list(robot.point_features[1:]))
    assert frame_geometry(robot, q, np.eye(4)).on_shaft[k]
    assert not frame_geometry(off, q, np.eye(4)).on_shaft[k]
    discs = marker_discs(off, base_features(off, q))
    assert discs is None or np.allclose(discs[1][k], 0.0)     # a point: no disc normals
