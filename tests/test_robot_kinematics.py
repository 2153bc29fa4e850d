"""Forward kinematics against explicit matrix products written out in the test."""
import json

import numpy as np
import pytest

from graphtrack.errors import InputError
from graphtrack.robot.description import load_dvrk_config, load_robot_json, save_robot_json
from graphtrack.robot.features import base_features, camera_features, shaft_lines
from graphtrack.robot.kinematics import check_joints, link_transforms
from graphtrack.robot.psm import psm_large_needle_driver
from importlib import resources


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def Tx(x):
    T = np.eye(4)
    T[0, 3] = x
    return T


def Tz(z):
    T = np.eye(4)
    T[2, 3] = z
    return T


Q = np.array([0.21, -0.33, 0.142, 0.7, -0.25, 0.31, 0.45])


def explicit_psm(q):
    """The classic dVRK PSM + Large Needle Driver, written joint by joint."""
    h = np.pi / 2
    T1 = Rx(h) @ Rz(q[0] + h)
    T2 = Rx(-h) @ Rz(q[1] - h)
    T3 = Rx(h) @ Tz(q[2] - 0.4318)
    T4 = Rz(q[3]) @ Tz(0.4162)
    T5 = Rx(-h) @ Rz(q[4] - h)
    T6 = Rx(-h) @ Tx(0.0091) @ Rz(q[5] - h)
    L = [np.eye(4)]
    for T in (T1, T2, T3, T4, T5, T6):
        L.append(L[-1] @ T)
    L.append(L[6] @ Rz(q[6] / 2))
    L.append(L[6] @ Rz(-q[6] / 2))
    return np.array(L)


def test_fk_matches_explicit_products():
    robot = psm_large_needle_driver()
    np.testing.assert_allclose(link_transforms(robot, Q), explicit_psm(Q), atol=1e-14)


def test_tip_position_independent():
    robot = psm_large_needle_driver()
    tip = base_features(robot, Q).tip
    ref = (explicit_psm(Q)[7] @ np.array([0, 0.0102, 0, 1.0]))[:3]
    np.testing.assert_allclose(tip, ref, atol=1e-14)
    # the tip is ~insertion depth from the remote centre of motion
    assert abs(np.linalg.norm(tip) - Q[2]) < 0.03


def test_dvrk_config_route_agrees_with_robot_json(tmp_path):
    robot = psm_large_needle_driver()
    save_robot_json(tmp_path / "robot.json", robot)
    from_json = load_robot_json(tmp_path / "robot.json")
    data = resources.files("graphtrack") / "data" / "dvrk"
    from_dvrk = load_dvrk_config(data / "psm.json", data / "LARGE_NEEDLE_DRIVER_400006.json", features_from=from_json)
    assert from_dvrk.has_gripper and from_dvrk.n_joints == 7
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(-1, 1, 7) * [1, 0.8, 0, 2, 1, 1, 0.5] + [0, 0, 0.15, 0, 0, 0, 0.5]
        np.testing.assert_allclose(link_transforms(from_dvrk, q), link_transforms(from_json, q), atol=1e-12)


def test_vectorised_over_joint_vectors_and_poses():
    robot = psm_large_needle_driver()
    rng = np.random.default_rng(1)
    qs = Q + rng.normal(size=(6, 7)) * 0.05
    L = link_transforms(robot, qs)
    for i in range(6):
        np.testing.assert_allclose(L[i], explicit_psm(qs[i]), atol=1e-14)
    E = np.tile(np.eye(4), (1000, 1, 1))
    E[:, :3, 3] = rng.normal(size=(1000, 3)) * 0.01 + [0, 0, 0.1]
    cam = camera_features(robot, Q, E)
    assert cam.points.shape == (1000, 4, 3) and cam.tip.shape == (1000, 3)
    assert cam.skeleton.shape == (1000, 5, 2, 3)
    base = base_features(robot, Q)
    np.testing.assert_allclose(cam.points[17], base.points + E[17, :3, 3])
    rho, theta, valid = shaft_lines(cam, np.array([[800.0, 0, 480], [0, 800, 270], [0, 0, 1]]))
    assert rho.shape == (1000, 2) and valid.shape == (1000,)


def test_prismatic_and_revolute_joint_types(tmp_path):
    doc = {"DH_params": [
        {"type": "prismatic", "alpha": 0.3, "A": 0.01, "theta": 0.2, "D": 0.05, "offset": 0.01},
        {"type": "revolute", "alpha": -0.4, "A": 0.02, "theta": 0.1, "D": 0.03, "offset": 0.5}]}
    (tmp_path / "robot.json").write_text(json.dumps(doc))
    robot = load_robot_json(tmp_path / "robot.json")
    q = np.array([0.07, 0.9])
    ref = Rx(0.3) @ Tx(0.01) @ Rz(0.2) @ Tz(0.05 + 0.01 + 0.07)
    ref = ref @ Rx(-0.4) @ Tx(0.02) @ Rz(0.1 + 0.5 + 0.9) @ Tz(0.03)
    np.testing.assert_allclose(link_transforms(robot, q)[-1], ref, atol=1e-14)


def test_check_joints_rejects_wrong_length_and_nan():
    robot = psm_large_needle_driver()
    with pytest.raises(InputError, match="expected 7 joint values"):
        check_joints(robot, np.zeros(6), "frame 3")
    with pytest.raises(InputError, match="NaN"):
        check_joints(robot, np.array([0, 0, 0.1, 0, np.nan, 0, 0]))


def test_dvrk_config_takes_the_features_robot_json_by_path(tmp_path):
    robot = psm_large_needle_driver()
    save_robot_json(tmp_path / "robot.json", robot)
    data = resources.files("graphtrack") / "data" / "dvrk"
    by_path = load_dvrk_config(data / "psm.json", data / "LARGE_NEEDLE_DRIVER_400006.json",
                               features_from=str(tmp_path / "robot.json"))
    assert by_path.tool_tip == load_robot_json(tmp_path / "robot.json").tool_tip
    assert len(by_path.point_features) == len(robot.point_features) > 0
