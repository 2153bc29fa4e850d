"""Simulator: --stereo leaves the left recording as it is; the right view; --randomize's record."""
import json

import cv2
import numpy as np
import pytest

from graphtrack.io.labels import read_labels
from graphtrack.robot.kinematics import link_transforms
from graphtrack.io.recording import open_recording
from graphtrack.sim import simulate
from graphtrack.sim.simulate import Simulation
from graphtrack.sim.stereo import rig

SIZE = (120, 160)


@pytest.mark.parametrize("randomize", [False, True])
def test_left_recording_is_the_same_with_and_without_stereo(tmp_path, randomize):
    kw = dict(scene="tissue", frames=4, seed=3, size=SIZE, form="folder", progress=False, randomize=randomize)
    a = simulate(tmp_path / "mono", **kw)
    b = simulate(tmp_path / "stereo", stereo=True, **kw)
    for name in ["truth.csv", "labels.csv", "joints.csv", "handeye.yaml"] + [f"frames/{i:06d}.png" for i in range(4)]:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert not (a / "frames_right").exists() and len(list((b / "frames_right").iterdir())) == 4
    assert (b / "labels_right.csv").is_file() and not (a / "labels_right.csv").exists()
    ca, cb = open_recording(a).calibration, open_recording(b).calibration
    assert ca.right is None and cb.right is not None
    np.testing.assert_array_equal(ca.left.K, cb.left.K)


def test_rig_geometry():
    R, T = rig(0.005, np.radians(2.0))
    C = -R.T @ T                         # right centre in the left frame: 5 mm along +x
    np.testing.assert_allclose(C, [0.005, 0, 0], atol=1e-15)
    z = R.T @ [0, 0, 1.0]                # right optical axis, toed in towards the left one
    assert z[0] == pytest.approx(-np.sin(np.radians(2.0)))
    t = C[0] / -z[0]                     # the axes cross at b / tan(vergence)
    assert t * z[2] == pytest.approx(0.005 / np.tan(np.radians(2.0)))


def test_right_labels_and_silhouette_follow_the_right_camera(tmp_path):
    out = simulate(tmp_path / "s", "structured", frames=3, seed=5, size=(180, 320), form="folder",
                   progress=False, noise_free=True, stereo=True)
    rec = open_recording(out)
    sim = Simulation("structured", 3, seed=5, size=(180, 320), noise_free=True, stereo=True)
    c = rec.calibration
    lab = read_labels(out / "labels_right.csv")
    for i, f in enumerate(rec.frames()):
        tip = sim.tip_cam[i]
        ref, _ = cv2.projectPoints(tip[None], cv2.Rodrigues(c.R)[0], c.T, c.right.K, c.right.dist)
        assert np.allclose(sim.tip_uv_right[i], ref.ravel(), atol=1e-6)
        if i in lab:
            assert np.hypot(*(lab[i] - ref.ravel())) < 6.0           # label noise 1.2 px
        # the shaft at 10 cm: the right image shows the wrist where the right camera projects it
        wrist = sim.L_true[i, 4, :3, 3]
        u, v = np.round(c.project_right(wrist)).astype(int)
        if 0 <= u < 320 and 0 <= v < 180:
            assert f.image_right[v, u].mean() < 200                 # not the white bench
        assert not np.array_equal(f.image, f.image_right)


def test_randomized_scenario_record(tmp_path):
    out = simulate(tmp_path / "r", "tissue", frames=90, seed=6, size=SIZE, form="folder", progress=False,
                   randomize=True)
    doc = json.loads((out / "scenario.json").read_text())
    he = doc["handeye_error"]
    assert 0 <= he["translation_mm"] <= 10 and 0 <= he["rotation_deg"] <= 5
    for o in doc["occlusions"]:
        assert o["kind"] in ("tissue", "instrument") and 0.3 <= o["target_coverage"] <= 1.0
        assert 15 <= o["end"] - o["start"] <= 90 and len(o["coverage"]) == o["end"] - o["start"]
        assert all(c is None or 0 <= c <= 1 for c in o["coverage"])
    # the tip-out intervals agree with truth.csv's tip, and such frames carry no label
    truth = np.genfromtxt(out / "truth.csv", delimiter=",", names=True)
    H, W = SIZE
    out_t = ~((truth["tip_u"] >= 0) & (truth["tip_u"] <= W - 1) & (truth["tip_v"] >= 0) & (truth["tip_v"] <= H - 1))
    flags = np.zeros(90, bool)
    for s, e in doc["out_of_view"]["tip_out"]:
        flags[s:e] = True
    np.testing.assert_array_equal(flags, out_t)
    assert not set(np.flatnonzero(out_t)) & set(read_labels(out / "labels.csv"))
    assert set(doc["effects"]) >= {"motion_blur", "lighting", "smoke", "haze", "sensor_noise"}


def test_excursion_takes_the_tip_out_of_view():
    from graphtrack.sim import motion

    sim = Simulation("structured", 60, seed=1, size=SIZE)
    q, delta = motion.excursion(sim.robot, sim.camera, sim.E_he, sim.q_true, 10, 10, 20)
    assert delta is not None and 0 < delta[2] <= sim.q_true[20:40, 2].min() - 0.05 + 1e-12
    np.testing.assert_array_equal(q[:10], sim.q_true[:10])
    np.testing.assert_array_equal(q[50:], sim.q_true[50:])
    np.testing.assert_allclose(q[20:40, 2], sim.q_true[20:40, 2] - delta[2])
    np.testing.assert_allclose(q[20:40, 0], sim.q_true[20:40, 0] + delta[0])
    L = sim.E_he @ link_transforms(sim.robot, q[20:40])      # independent: the tip leaves the image
    tip = L[:, 7, :3, :3] @ np.array(sim.robot.tool_tip.position) + L[:, 7, :3, 3]
    uv, _ = cv2.projectPoints(tip, np.zeros(3), np.zeros(3), sim.camera.K, sim.camera.dist)
    uv = uv.reshape(-1, 2)
    inside = (tip[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < SIZE[1]) & (uv[:, 1] >= 0) & (uv[:, 1] < SIZE[0])
    assert not inside.any()
