"""`graphtrack track --estimator kinematics` end to end, and bad input at the CLI."""
import csv
import json
from pathlib import Path
from types import SimpleNamespace as NS

import cv2
import numpy as np
import pytest
import yaml

from graphtrack.cli import main
from graphtrack.geometry.camera import Calibration, Camera, save_calibration
from graphtrack.io.bag_write import write_bag
from graphtrack.io.folder import write_folder
from graphtrack.io.handeye import save_handeye
from graphtrack.robot.description import save_robot_json
from graphtrack.robot.psm import psm_large_needle_driver
from test_robot_kinematics import explicit_psm

H, W = 120, 160
K = np.array([[150.0, 0, 79.2], [0, 151.0, 60.3], [0, 0, 1]])
D = np.array([-0.25, 0.08, 0.001, -0.0005, -0.01])


def look_at(eye, target):
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross([0, 0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in base
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T  # camera-from-base


def joints(n, seed=0):
    rng = np.random.default_rng(seed)
    q = np.array([0.1, -0.1, 0.14, 0.3, 0.1, -0.1, 0.4])
    return q + rng.normal(size=(n, 7)) * [0.02, 0.02, 0.003, 0.1, 0.1, 0.1, 0.05]


def make_sequence(root: Path, form="folder", n=6, labels=True, frames_override=None):
    root.mkdir(parents=True, exist_ok=True)
    robot = psm_large_needle_driver()
    save_robot_json(root / "robot.json", robot)
    save_calibration(root / "camera_calibration.yaml", Calibration(Camera(K, D, H, W)))
    tip0 = (explicit_psm(joints(1)[0])[7] @ [0, 0.0102, 0, 1])[:3]
    E = look_at(tip0 + np.array([0.05, -0.06, 0.05]), tip0)
    save_handeye(root / "handeye.yaml", E)
    qs = joints(n)
    frames = frames_override or [NS(stamp=100.0 + i / 30, image=np.full((H, W, 3), 128, np.uint8),
                                     joints=qs[i, :6], jaw=qs[i, 6]) for i in range(n)]
    if form == "folder":
        write_folder(root, frames)
    else:
        write_bag(root / "rec.bag", frames)
    if labels:
        with open(root / "labels.csv", "w") as f:
            f.write("frame,u,v\n" + "".join(f"{i},{W/2},{H/2}\n" for i in range(n)))
    return root, E, qs


def independent_tip(E_file: Path, q):
    """Tip through handeye.yaml (mm, Rodrigues) and explicit FK, projected by OpenCV."""
    doc = yaml.safe_load(E_file.read_text())
    rvec = np.asarray(doc["PSM1_rvec"], float)
    tvec = np.asarray(doc["PSM1_tvec"], float) / 1000.0
    tip_base = (explicit_psm(q)[7] @ [0, 0.0102, 0, 1])[:3]
    uv, _ = cv2.projectPoints(tip_base[None], rvec, tvec, K, D)
    return uv.reshape(2)


@pytest.mark.parametrize("form", ["folder", "bag"])
def test_kinematics_track_outputs_and_tip(tmp_path, form):
    seq, E, qs = make_sequence(tmp_path / "seq", form)
    out = tmp_path / "out"
    assert main(["track", str(seq), "--estimator", "kinematics", "--out", str(out), "--quiet"]) == 0
    rows = list(csv.reader(open(out / "trajectory.csv")))
    assert rows[0][:12] == "frame,stamp,tx,ty,tz,qx,qy,qz,qw,tip_u,tip_v,ms".split(",")
    assert len(rows) == 1 + len(qs)
    for r in rows[1:]:
        i = int(r[0])
        np.testing.assert_allclose([float(r[2]), float(r[3]), float(r[4])], E[:3, 3], atol=1e-9)
        tip = np.array([float(r[9]), float(r[10])])
        assert np.linalg.norm(tip - independent_tip(seq / "handeye.yaml", qs[i])) < 0.05
    tum = (out / "trajectory.tum").read_text().split("\n")
    assert len(tum[0].split()) == 8
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames_scored"] == len(qs)
    for k in ("mean", "std", "median", "p95"):
        assert k in m["tip_error_px"] and k in m["tip_error_percent_diagonal"]


def run_cli(args, capsys):
    code = main(args)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def test_missing_file_exit_2(tmp_path, capsys):
    seq, _, _ = make_sequence(tmp_path / "seq")
    (seq / "handeye.yaml").unlink()
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "handeye.yaml" in err and len(err.strip().splitlines()) == 1


def test_missing_key_exit_2(tmp_path, capsys):
    seq, _, _ = make_sequence(tmp_path / "seq")
    doc = json.loads((seq / "robot.json").read_text())
    del doc["DH_params"][1]["alpha"]
    (seq / "robot.json").write_text(json.dumps(doc))
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "robot.json" in err and "alpha" in err


def test_mistyped_key_exit_2(tmp_path, capsys):
    seq, _, _ = make_sequence(tmp_path / "seq")
    (seq / "handeye.yaml").write_text("PSM1_tvec: [1, 2, x]\nPSM1_rvec: [0, 0, 0]\n")
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "PSM1_tvec" in err


def test_wrong_joint_count_is_skipped_and_counted(tmp_path, capsys):
    qs = joints(4)
    frames = [NS(stamp=i / 30, image=np.full((H, W, 3), 128, np.uint8), joints=qs[i, :6], jaw=qs[i, 6])
              for i in range(4)]
    seq, _, _ = make_sequence(tmp_path / "seq", frames_override=frames, n=4)
    # rewrite joints.csv with a missing value in frame 2
    lines = (seq / "joints.csv").read_text().splitlines()
    lines[3] = ",".join(lines[3].split(",")[:-2] + [lines[3].split(",")[-1]])
    (seq / "joints.csv").write_text("\n".join(lines) + "\n")
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    if code == 0:
        m = json.loads((tmp_path / "o" / "metrics.json").read_text())
        assert m["frames_skipped"] == 1
    else:
        assert code == 2 and "joints.csv" in err


def test_nan_joints_skipped_and_counted(tmp_path, capsys):
    qs = joints(5)
    qs[2, 1] = np.nan
    frames = [NS(stamp=i / 30, image=np.full((H, W, 3), 128, np.uint8), joints=qs[i, :6], jaw=qs[i, 6])
              for i in range(5)]
    seq, _, _ = make_sequence(tmp_path / "seq", frames_override=frames, n=5, form="bag")
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 0 and "frame 2" in err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["frames_skipped"] == 1 and m["skipped_reasons"] == {"nan_joints": 1}
    assert m["frames_scored"] == 4


def test_image_size_disagrees_skipped(tmp_path, capsys):
    qs = joints(3)
    frames = [NS(stamp=i / 30, image=np.full((H if i != 1 else H + 2, W, 3), 128, np.uint8),
                 joints=qs[i, :6], jaw=qs[i, 6]) for i in range(3)]
    seq, _, _ = make_sequence(tmp_path / "seq", frames_override=frames, n=3, form="bag")
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 0 and "frame 1" in err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["skipped_reasons"] == {"image_size": 1}


def test_bag_without_joint_topic_exit_2(tmp_path, capsys):
    from rosbags.rosbag1 import Writer

    seq, _, _ = make_sequence(tmp_path / "seq", form="folder", n=2)
    for p in list((seq / "frames").iterdir()):
        p.unlink()
    (seq / "frames").rmdir()
    (seq / "joints.csv").unlink()
    with Writer(seq / "rec.bag"):  # an empty but valid bag
        pass
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and ("/stereo/left/image" in err or "/dvrk/PSM1" in err or "rec.bag" in err)


def test_truncated_bag_runs_with_warning(tmp_path, capsys):
    seq, _, _ = make_sequence(tmp_path / "seq", form="bag", n=8)
    data = (seq / "rec.bag").read_bytes()
    (seq / "rec.bag").write_bytes(data[: int(len(data) * 0.6)])
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code in (0, 2)
    if code == 2:
        assert "rec.bag" in err
    else:
        assert "warning" in err
        rows = (tmp_path / "o" / "trajectory.csv").read_text().splitlines()
        assert 1 < len(rows) < 9


def test_unwritable_out_exit_2(tmp_path, capsys):
    seq, _, _ = make_sequence(tmp_path / "seq")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, err = run_cli(["track", str(seq), "--out", str(blocker / "sub")], capsys)
    assert code == 2 and "sub" in err


def test_tip_feature_option_and_missing_tool_tip(tmp_path, capsys):
    seq, E, qs = make_sequence(tmp_path / "seq")
    doc = json.loads((seq / "robot.json").read_text())
    del doc["tool_tip"]
    (seq / "robot.json").write_text(json.dumps(doc))
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "tool_tip" in err and "--tip-feature" in err
    code, err = run_cli(["track", str(seq), "--out", str(tmp_path / "o"), "--tip-feature", "nope"], capsys)
    assert code == 2 and "marker_0" in err
    out = tmp_path / "o2"
    assert main(["track", str(seq), "--out", str(out), "--tip-feature", "marker_0", "--quiet"]) == 0
    rows = list(csv.reader(open(out / "trajectory.csv")))
    # marker_0 of the PSM model is on link 4 at (r, 0, -0.010): project it independently
    doc = yaml.safe_load((seq / "handeye.yaml").read_text())
    q = qs[int(rows[1][0])]
    p = (explicit_psm(q)[4] @ [0.004, 0, -0.010, 1])[:3]
    uv, _ = cv2.projectPoints(p[None], np.asarray(doc["PSM1_rvec"], float),
                              np.asarray(doc["PSM1_tvec"], float) / 1000, K, D)
    assert np.linalg.norm(np.array([float(rows[1][9]), float(rows[1][10])]) - uv.reshape(2)) < 0.05


def test_near_image_is_judged_without_the_distortion_fold_back():
    """A wide-angle lens (k1 = -0.4): a tip at X/Z = 2, 1000 px beside a 1920x1080 image, is
    near it, though the distortion polynomial (OpenCV's projectPoints, the oracle) folds it
    thousands of pixels the other way; behind the camera or 3 diagonals off is not near."""
    import cv2

    from graphtrack.geometry.camera import Camera
    from graphtrack.track import near_image

    K = np.array([[1000.0, 0, 960], [0, 1000.0, 540], [0, 0, 1]])
    D = np.array([-0.4, 0.25, 0, 0, -0.1])
    cam = Camera(K, D, 1080, 1920)
    pts = np.array([[2.0, 0.0, 1.0], [0.1, 0.0, -1.0], [7.0, 0.0, 1.0], [0.1, 0.1, 1.0]])
    raw = cv2.projectPoints(pts[:1], np.zeros(3), np.zeros(3), K, D)[0].reshape(2)
    assert raw[0] < -cam.diagonal                      # folded far to the left
    assert near_image(cam, pts).tolist() == [True, False, False, True]
