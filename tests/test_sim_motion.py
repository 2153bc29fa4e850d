"""The simulator's motion (graphtrack.sim.motion): limits, smoothness, seeds, errors."""
import numpy as np
import pytest

from graphtrack.geometry.se3 import matrix_to_bw
from graphtrack.robot.kinematics import link_transforms
from graphtrack.robot.psm import psm_large_needle_driver
from graphtrack.sim import motion
from graphtrack.sim.synthetic import make_camera

FPS = 30.0
ROBOT = psm_large_needle_driver()
CAM = make_camera(960, 540, 1000.0)


def camera_pose():
    return motion.look_at_workspace(ROBOT, motion.Q0, 0.12, 65.0, 0.3, -50.0, 0.1 * CAM.width, CAM.K[0, 0])


def test_sinusoids_bounded_smooth_and_seeded():
    """Three sinusoids per joint, amplitudes split by Dirichlet weights (sum 1), f <= 0.25 Hz:
    |x| <= A, |dx| <= A 2 pi fmax / fps, |d2x| <= A (2 pi fmax / fps)^2 per frame."""
    A = motion.AMPLITUDE
    x = motion.sinusoids(np.random.default_rng(3), 600, FPS, A)
    assert x.shape == (600, 7)
    assert np.all(np.abs(x) <= A + 1e-12)
    w = 2 * np.pi * 0.25 / FPS
    assert np.all(np.abs(np.diff(x, axis=0)) <= A * w + 1e-12)
    assert np.all(np.abs(np.diff(x, 2, axis=0)) <= A * w * w + 1e-12)
    np.testing.assert_array_equal(x, motion.sinusoids(np.random.default_rng(3), 600, FPS, A))
    assert not np.array_equal(x, motion.sinusoids(np.random.default_rng(4), 600, FPS, A))


def test_true_trajectory_in_limits_in_view_and_seeded():
    E = camera_pose()
    q = motion.true_trajectory(ROBOT, CAM, E, motion.Q0, 300, FPS, np.random.default_rng(5))
    lim = ROBOT.joint_limits
    assert q.shape == (300, 7)
    assert np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1])
    assert np.all(motion.view_ok(ROBOT, CAM, E, q))
    # clipping is 1-Lipschitz: the per-frame step bound of the sinusoids still holds
    assert np.all(np.abs(np.diff(q, axis=0)) <= motion.AMPLITUDE * 2 * np.pi * 0.25 / FPS + 1e-12)
    again = motion.true_trajectory(ROBOT, CAM, E, motion.Q0, 300, FPS, np.random.default_rng(5))
    np.testing.assert_array_equal(q, again)


def test_true_trajectory_falls_back_to_q0():
    """A camera that never sees the tool: every draw fails, the trajectory rests at q0."""
    E = np.eye(4)
    E[2, 3] = -1.0                       # the robot 1 m behind the camera
    q = motion.true_trajectory(ROBOT, CAM, E, motion.Q0, 10, FPS, np.random.default_rng(0), tries=3)
    np.testing.assert_array_equal(q, np.repeat(motion.Q0[None], 10, 0))


def test_readings_bias_and_noise():
    """Joints 1-2: |bias| <= (0.6 + 0.4 + 0.25) 0.8 deg plus white 0.03 deg; joint 3:
    1.25 mm plus 0.05 mm; the wrist and jaw only white noise (0.15 / 0.3 deg)."""
    q = motion.true_trajectory(ROBOT, CAM, camera_pose(), motion.Q0, 600, FPS, np.random.default_rng(1))
    np.testing.assert_array_equal(motion.readings(np.random.default_rng(0), q, FPS, noise_free=True), q)
    r = motion.readings(np.random.default_rng(2), q, FPS)
    d = r - q
    bound = 1.25 * np.array([np.radians(0.8), np.radians(0.8), 0.001]) + 5 * np.array([np.radians(0.03)] * 2 + [5e-5])
    assert np.all(np.abs(d[:, :3]) <= bound)
    white = np.radians([0.15, 0.15, 0.15, 0.3])
    np.testing.assert_allclose(d[:, 3:].std(0), white, rtol=0.15)
    np.testing.assert_allclose(d[:, 3:].mean(0), 0.0, atol=4 * white.max() / np.sqrt(600))
    np.testing.assert_array_equal(r, motion.readings(np.random.default_rng(2), q, FPS))


@pytest.mark.parametrize("seed", range(5))
def test_handeye_error_magnitudes(seed):
    D = motion.handeye_error(np.random.default_rng(seed))
    np.testing.assert_allclose(D[:3, :3] @ D[:3, :3].T, np.eye(3), atol=1e-12)
    bw = matrix_to_bw(D)
    assert 2e-3 - 1e-12 <= np.linalg.norm(bw[:3]) <= 5e-3 + 1e-12
    assert 1.0 - 1e-9 <= np.degrees(np.linalg.norm(bw[3:])) <= 3.0 + 1e-9


def test_lumped_error_by_hand():
    """Exact readings: E_t = E_true. A reading off by dq: E_t = E_true T4(q) T4(q~)^-1."""
    E = camera_pose()
    q = motion.true_trajectory(ROBOT, CAM, E, motion.Q0, 20, FPS, np.random.default_rng(0))
    Et = motion.lumped_error(ROBOT, E, q, q)
    np.testing.assert_allclose(Et, np.repeat(E[None], 20, 0), atol=1e-12)
    qr = q + np.array([0.01, -0.01, 0.001, 0.02, 0.0, 0.0, 0.0])
    Et = motion.lumped_error(ROBOT, E, q, qr)
    for k in (0, 19):
        want = E @ link_transforms(ROBOT, q[k])[4] @ np.linalg.inv(link_transforms(ROBOT, qr[k])[4])
        np.testing.assert_allclose(Et[k], want, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 90.0, 180.0, 270.0, 35.0])
def test_shaft_angle_places_the_entry_and_keeps_the_seeds_other_draws(angle):
    """Simulation(shaft_angle=a): the shaft's image direction from the wrist towards the RCM
    (projected with the true pose at frame 0, the pinhole oracle K [X / Z]) points a deg
    counter-clockwise from the image's right, within the joint motion's swing; the
    hand-eye error drawn from the seed is the same as without it."""
    from graphtrack.sim.simulate import Simulation

    sim = Simulation("tissue", 5, seed=11, size=(540, 960), shaft_angle=angle)
    L = sim.L_true[0]
    wrist = L[4, :3, 3]
    rcm = wrist - 0.05 * L[4, :3, 2]                     # 5 cm back along the shaft (link 4 z: towards the tip)
    K = sim.camera.K
    px = [(K @ (p / p[2]))[:2] for p in (wrist, rcm)]
    d = px[1] - px[0]
    got = np.degrees(np.arctan2(-d[1], d[0]))          # counter-clockwise on screen (y down)
    assert abs((got - angle + 180.0) % 360.0 - 180.0) < 15.0
    np.testing.assert_array_equal(sim.delta, Simulation("tissue", 5, seed=11, size=(540, 960)).delta)


def test_handeye_error_sets_its_size_and_keeps_the_seeds_other_draws():
    """Simulation(handeye_error=(b m, w rad)): Delta's translation is b long and its rotation
    w (scipy's rotation vector as the oracle), in the directions the seed draws without it; the
    view and the motion are the seed's."""
    from scipy.spatial.transform import Rotation

    from graphtrack.errors import InputError
    from graphtrack.sim.simulate import Simulation

    drawn = Simulation("structured", 5, seed=12, size=(270, 480), randomize=True)
    sim = Simulation("structured", 5, seed=12, size=(270, 480), randomize=True,
                     handeye_error=(0.025, np.radians(10.0)))
    t, rv = sim.delta[:3, 3], Rotation.from_matrix(sim.delta[:3, :3]).as_rotvec()
    assert np.linalg.norm(t) == pytest.approx(0.025) and np.linalg.norm(rv) == pytest.approx(np.radians(10.0))
    t0, rv0 = drawn.delta[:3, 3], Rotation.from_matrix(drawn.delta[:3, :3]).as_rotvec()
    np.testing.assert_allclose(t / np.linalg.norm(t), t0 / np.linalg.norm(t0), atol=1e-12)
    np.testing.assert_allclose(rv / np.linalg.norm(rv), rv0 / np.linalg.norm(rv0), atol=1e-9)
    np.testing.assert_array_equal(sim.E_he, drawn.E_he)
    np.testing.assert_array_equal(sim.q_read, drawn.q_read)
    for bad in [(0.2, 0.1), (0.01, -0.1), (0.01,), "x"]:
        with pytest.raises(InputError, match="hand-eye error"):
            Simulation("structured", 5, seed=12, size=(270, 480), handeye_error=bad)
    with pytest.raises(InputError, match="shaft angle"):
        Simulation("structured", 5, seed=12, size=(270, 480), shaft_angle=float("nan"))
