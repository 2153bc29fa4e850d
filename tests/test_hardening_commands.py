"""Bad input to the commands other than ``track`` (train, simulate, robot, compare,
detect) and to the recording readers: each ends with one line naming the option, file,
topic or frame and exit status 2, or with a counted per-frame skip, and the codec
libraries' own messages never reach the terminal."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from graphtrack.cli import main
from graphtrack.errors import FrameError, InputError
from graphtrack.io.recording import open_recording
from graphtrack.io.topics import TopicSelection

from test_io_recording import (JAW, JOINTS, NO_ROBOT, image_msg, joint_msg, typestore, write_custom_bag,
                               write_meta)

REPO = Path(__file__).resolve().parents[1]
DVRK = REPO / "graphtrack" / "data" / "dvrk"
IMAGE = "/stereo/left/image"


def run_cli(args, capsys) -> tuple[int, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


def error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("graphtrack: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def folder_rec(tmp_path_factory):
    from graphtrack.sim.simulate import simulate

    return simulate(tmp_path_factory.mktemp("rec") / "folder", frames=6, size=(270, 480), form="folder",
                    progress=False)


# -- train ----------------------------------------------------------------------------------
def test_train_refuses_what_would_fail_after_hours(tmp_path, capsys):
    out = tmp_path / "w.pt"
    cases = [(["--out", tmp_path], "is a folder"),
             (["--out", tmp_path / "missing" / "w.pt"], "folder not found"),
             (["--out", out, "--seed", "-1"], "--seed must be an integer in 0..4294967295, got -1"),
             (["--out", out, "--seed", str(2**64)], "--seed must be an integer in 0..4294967295"),
             (["--out", out, "--epochs", "0"], "--epochs must be at least 1"),
             (["--out", tmp_path / "w.txt"], "--out " + str(tmp_path / "w.txt") + ": name a .pt file")]
    text = tmp_path / "notes.pt"
    text.write_text("my notes")
    cases += [(["--out", out, "--init", text], f"--init {text}: not a torch weights file"),   # before simulating
              (["--out", text], f"--out {text}: not a torch weights file (state dict) (")]
    for args, words in cases:
        code, err = run_cli(["train", "--quiet", *args], capsys)
        assert code == 2 and words in error_line(err), (args, err)
    assert not out.exists() and text.read_text() == "my notes"


def test_train_names_a_data_cache_it_cannot_use(tmp_path, capsys):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip at all")
    keyless = tmp_path / "keyless.npz"
    np.savez(keyless, frames=np.zeros((2, 4, 4, 3), np.uint8))
    shaped = tmp_path / "shaped.npz"
    np.savez(shaped, images=np.zeros((2, 4, 4), np.uint8), segments=np.zeros((2, 6, 4), np.float32))
    tiny = tmp_path / "tiny.npz"
    np.savez(tiny, images=np.zeros((1, 1, 1, 3), np.uint8), segments=np.zeros((1, 6, 4), np.float32))
    no_segments = tmp_path / "no_segments.npz"
    np.savez(no_segments, images=np.zeros((2, 32, 32, 3), np.uint8), segments=np.zeros((2, 0, 4), np.float32))
    words_as_segments = tmp_path / "words.npz"
    np.savez(words_as_segments, images=np.zeros((2, 32, 32, 3), np.uint8), segments=np.full((2, 6, 4), "x"))
    for path, words in ((garbage, "not a readable .npz"), (keyless, "no 'images' or 'segments'"),
                        (shaped, "'images' must be (N, h, w, 3) uint8"), (tiny, "h, w >= 16"),
                        (no_segments, "S >= 1"), (words_as_segments, "'segments' must be numbers")):
        code, err = run_cli(["train", "--quiet", "--out", tmp_path / "w.pt", "--data", path], capsys)
        line = error_line(err)
        assert code == 2 and str(path) in line and words in line, err
    assert not (tmp_path / "w.pt").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_train_refuses_a_read_only_output_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        code, err = run_cli(["train", "--quiet", "--out", ro / "w.pt"], capsys)
        assert code == 2 and "not writable (--out)" in error_line(err)
    finally:
        ro.chmod(0o700)


def test_simulate_and_track_refuse_a_negative_seed_and_absurd_particles(tmp_path, capsys):
    code, err = run_cli(["simulate", tmp_path / "s", "--seed", "-1", "--no-progress"], capsys)
    assert code == 2 and "--seed must be an integer in 0..4294967295" in error_line(err)
    assert not (tmp_path / "s").exists()
    code, err = run_cli(["track", tmp_path / "none", "--out", tmp_path / "o", "--estimator", "pf",
                         "--particles", "1000000000"], capsys)
    assert code == 2 and "--particles must be a whole number between 1 and 100000" in error_line(err)


# -- robot ----------------------------------------------------------------------------------
def _tool_without_jaw(path: Path, links: int = 3) -> Path:
    import re

    text = re.sub(r"/\*.*?\*/", "", (DVRK / "LARGE_NEEDLE_DRIVER_400006.json").read_text(), flags=re.S)
    doc = json.loads(re.sub(r"//[^\n]*", "", text))
    doc.pop("jaw")
    dh = doc["DH"]
    key = "links" if "links" in dh else "joints"
    dh[key] = (dh[key] * 3)[:links]
    path.write_text(json.dumps(doc))
    return path


def test_robot_refuses_files_that_are_not_dvrk_objects(tmp_path, capsys):
    listed = tmp_path / "list.json"
    listed.write_text("[1, 2]")
    out = tmp_path / "robot.json"
    code, err = run_cli(["robot", listed, DVRK / "LARGE_NEEDLE_DRIVER_400006.json", "--out", out], capsys)
    assert code == 2 and "list.json: document: expected a JSON object (a dVRK configuration file), got an array" \
        in error_line(err)
    four = _tool_without_jaw(tmp_path / "four.json", links=4)
    code, err = run_cli(["robot", DVRK / "psm.json", four, "--out", out], capsys)
    assert code == 2 and "four.json: DH: expected the tool's 3 joints (4-6) or a whole PSM's 6, got 4" \
        in error_line(err)
    assert not out.exists()


def test_robot_blames_the_jawless_tool_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "robot.json"
    code, err = run_cli(["robot", DVRK / "psm.json", _tool_without_jaw(tmp_path / "nojaw.json"),
                         "--out", out], capsys)
    line = error_line(err)
    assert code == 2 and "nojaw.json has no 'jaw' section" in line and "--features-from" in line
    assert 'add "jaw": {} to the tool file' in line
    assert not out.exists()
    # following that advice builds the robot
    tool = tmp_path / "nojaw.json"
    tool.write_text(json.dumps({**json.loads(tool.read_text()), "jaw": {}}))
    code, err = run_cli(["robot", DVRK / "psm.json", tool, "--out", out], capsys)
    assert code == 0, err
    assert json.loads(out.read_text())["has_gripper"] is True


# -- compare / detect -----------------------------------------------------------------------
def test_compare_refuses_an_unreachable_ray_cluster_quickly(folder_rec, tmp_path, capsys):
    t = time.perf_counter()
    code, err = run_cli(["compare", folder_rec, "--out", tmp_path / "study", "--estimators", "kinematics",
                         "--quiet", "--ray", "127.0.0.1:1"], capsys)
    assert code == 2 and "--ray 127.0.0.1:1: no Ray cluster answers there" in error_line(err)
    assert time.perf_counter() - t < 60


def test_a_study_folder_without_finished_cells_takes_corrected_options(folder_rec, tmp_path, capsys):
    study = tmp_path / "study"
    args = ["compare", folder_rec, "--out", study, "--estimators", "kinematics", "--quiet"]
    code, err = run_cli(args + ["--arm", "PSM2"], capsys)     # the recording's handeye.yaml is PSM1's
    assert code == 2 and "PSM2" in err
    code, err = run_cli(args, capsys)                          # corrected: accepted, not "other options"
    assert code == 0, err
    code, err = run_cli(args + ["--arm", "PSM2"], capsys)     # now a cell has finished: refused
    assert code == 2 and "holds a study made with other options (arm: None there, 'PSM2' now)" in error_line(err)
    code, err = run_cli(args + ["--ray", ""], capsys)
    assert code == 2 and "--ray : expected 'local', 'auto' or a cluster address" in error_line(err)


def test_compare_refuses_contradicting_views_and_takes_the_arm(folder_rec, tmp_path, capsys):
    code, err = run_cli(["compare", folder_rec, "--out", tmp_path / "a", "--stereo", "both", "--mono"], capsys)
    assert code == 2 and "--mono and --stereo both contradict" in error_line(err)
    code, err = run_cli(["compare", folder_rec, "--out", tmp_path / "b", "--estimators", "kinematics",
                         "--quiet", "--arm", "PSM1"], capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "b" / "study.json").read_text())["options"]["arm"] == "PSM1"


def test_detect_takes_the_arm_and_notes_topics_a_folder_cannot_use(folder_rec, tmp_path, capsys):
    code, err = run_cli(["detect", folder_rec, "--out", tmp_path / "d", "--quiet", "--max-frames", "2",
                         "--arm", "PSM1", "--joint-topic", "/x/joints"], capsys)
    assert code == 0, err
    rec = open_recording(folder_rec, topics=TopicSelection(joint="/x/joints"))
    assert any("--joint-topic ignored" in w for w in rec.warnings), rec.warnings


# -- recordings: notes on parts that are not used -------------------------------------------
def test_notes_on_right_inputs_a_recording_cannot_use(folder_rec, tmp_path):
    import shutil

    rec_dir = tmp_path / "rec"
    shutil.copytree(folder_rec, rec_dir)
    (rec_dir / "frames_right").write_text("not a folder")
    shutil.copy(rec_dir / "labels.csv", rec_dir / "labels_right.csv")
    warnings = open_recording(rec_dir).warnings
    assert any("frames_right: not a folder" in w for w in warnings), warnings
    assert any("labels_right.csv: not scored: camera_calibration.yaml has no right camera (K2, D2, R, T)" in w
               for w in warnings), warnings


def test_right_labels_need_the_right_camera_not_its_images(tmp_path):
    """labels_right.csv is scored through K2, D2, R, T alone (the estimate projected into
    the right camera), so a stereo recording whose right images are unusable (here numbered
    from 1) scores it, and no note says otherwise."""
    from graphtrack.cli import main
    from graphtrack.sim.simulate import simulate

    rec = simulate(tmp_path / "rec", frames=4, size=(270, 480), form="folder", progress=False, stereo=True)
    right = sorted((rec / "frames_right").iterdir())
    for p in reversed(right):
        stem = int(p.stem)
        p.rename(p.with_name(f"{stem + 1:0{len(p.stem)}d}{p.suffix}"))
    warnings = open_recording(rec).warnings
    assert not any("labels_right.csv" in w for w in warnings), warnings
    assert main(["track", str(rec), "--out", str(tmp_path / "run"), "--estimator", "kinematics", "--quiet"]) == 0
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["frames_scored_right"] == 4 and m["tip_error_right_px"]["mean"] >= 0


# -- bags: per-frame problems are counted skips, whole-bag ones one line ----------------------
H, W = 48, 64


def _bag(tmp_path, n=6, joint_offset_ns=0, odd_frame=None, jaw_values=1, missing_joints=(), missing_jaw=(),
         empty_jaw=(), q=(0.1,) * 6, jaw_value=0.2):
    ts = typestore()
    seq = write_meta(tmp_path / "seq", h=H, w=W)
    img = np.full((H, W, 3), 90, np.uint8)
    msgs = []
    for i in range(n):
        t = 1_600_000_000 * 10**9 + i * 33_333_333
        if i == odd_frame:
            mono16 = np.zeros((H, W * 2), np.uint8)
            m = image_msg(ts, t, mono16[:, :W], encoding="mono16")
            m = type(m)(header=m.header, height=H, width=W, encoding="mono16", is_bigendian=0, step=2 * W,
                        data=mono16.ravel())
        else:
            m = image_msg(ts, t, img)
        msgs.append((IMAGE, "sensor_msgs/msg/Image", t, m))
        if i not in missing_joints:
            msgs.append((JOINTS, "sensor_msgs/msg/JointState", t, joint_msg(ts, t + joint_offset_ns, list(q))))
        if i not in missing_jaw:
            jaw = [] if i in empty_jaw else [jaw_value] * jaw_values
            msgs.append((JAW, "sensor_msgs/msg/JointState", t, joint_msg(ts, t, jaw)))
    write_custom_bag(seq / "rec.bag", msgs)
    return seq


def test_an_unsupported_encoding_mid_bag_is_one_counted_skip(tmp_path):
    out = list(open_recording(_bag(tmp_path, odd_frame=3), **NO_ROBOT).frames())
    bad = [f for f in out if isinstance(f, FrameError)]
    assert [f.frame for f in bad] == [3] and bad[0].reason == "corrupt_image" and "mono16" in str(bad[0])


def test_joints_on_another_clock_or_missing_skip_the_frames(tmp_path):
    out = list(open_recording(_bag(tmp_path / "a", joint_offset_ns=3600 * 10**9), **NO_ROBOT).frames())
    assert all(isinstance(f, FrameError) and f.reason == "no_joint_reading" for f in out)
    assert "3600.000 s" in str(out[0])
    # joints lost from frame 1 to 24 of 30 (30 fps): frames farther than 0.2 s from a reading are skipped
    out = list(open_recording(_bag(tmp_path / "b", n=30, missing_joints=range(1, 25)), **NO_ROBOT).frames())
    far = [i for i in range(1, 25) if min(i, 25 - i) * 33_333_333 > 0.2e9]
    assert far == list(range(7, 19))
    assert [f.frame for f in out if isinstance(f, FrameError)] == far
    assert len(out) == 30
    # --max-joint-gap overrides the rule: 0.5 s keeps frames up to 15 frames from a reading, 0.1 s skips more
    for gap in (0.5, 0.1):
        rec = open_recording(tmp_path / "b" / "seq", **NO_ROBOT, topics=TopicSelection(joint_gap=gap))
        far = [i for i in range(1, 25) if min(i, 25 - i) * 33_333_333 > gap * 1e9]
        assert [f.frame for f in rec.frames() if isinstance(f, FrameError)] == far
    for bad in (0.0, -1.0, float("nan"), 11.0, True):
        with pytest.raises(InputError, match=r"--max-joint-gap: seconds in \(0, 10\]"):
            TopicSelection(joint_gap=bad)


def test_joints_recorded_at_a_low_rate_are_used_and_a_lost_jaw_skips(tmp_path):
    # joints at 2 Hz (every 15th frame at 30 fps): within 3 median periods, so every frame is kept
    slow = [i for i in range(60) if i % 15]
    out = list(open_recording(_bag(tmp_path / "a", n=60, missing_joints=slow), **NO_ROBOT).frames())
    assert not [f for f in out if isinstance(f, FrameError)]
    # the jaw lost from frame 1 to 24: the frames more than 0.2 s from a jaw reading are skipped
    out = list(open_recording(_bag(tmp_path / "b", n=30, missing_jaw=range(1, 25)), **NO_ROBOT).frames())
    bad = [f for f in out if isinstance(f, FrameError)]
    assert [f.frame for f in bad] == list(range(7, 19)) and JAW in str(bad[0])


def test_a_bag_in_degrees_or_millimetres_is_refused(tmp_path):
    from test_io_joint_units import PSM

    psm = {"robot_loader": lambda p: PSM, "expected_joints": 6}
    with pytest.raises(InputError, match=r"rec\.bag: /dvrk/PSM1/state_joint_current: 6 of 6 messages hold readings "
                                         r"no arm makes in radians and metres \(first: message 0, q3 = 120 is beyond \|q\| <= 1 m"):
        list(open_recording(_bag(tmp_path / "a", q=(0.1, 0.1, 120.0, 0.1, 0.1, 0.1)), **psm).frames())
    with pytest.raises(InputError, match=r"state_jaw_current: 6 of 6 messages .*jaw = 40 is beyond a full turn"):
        list(open_recording(_bag(tmp_path / "b", jaw_value=40.0), **psm).frames())
    assert len(list(open_recording(_bag(tmp_path / "c"), **psm).frames())) == 6
    # every jaw message empty (a table without a column): their frames are nan_joints skips, no crash
    out = list(open_recording(_bag(tmp_path / "d", empty_jaw=range(6)), **psm).frames())
    assert [f.reason for f in out] == ["nan_joints"] * 6


def test_a_jaw_topic_with_several_values_is_refused_and_an_empty_one_is_nan(tmp_path):
    with pytest.raises(InputError, match=r"state_jaw_current: a jaw message holds one position.* holds 6"):
        list(open_recording(_bag(tmp_path / "a", jaw_values=6), **NO_ROBOT).frames())
    out = list(open_recording(_bag(tmp_path / "b", empty_jaw=[2]), **NO_ROBOT).frames())
    assert isinstance(out[2], FrameError) and out[2].reason == "nan_joints"   # a counted skip, not a refusal
    assert all(f.jaw == 0.2 for k, f in enumerate(out) if k != 2)


# -- codec messages -------------------------------------------------------------------------
def test_a_jaw_as_the_joint_messages_last_value_is_named(tmp_path):
    """No jaw messages and joint messages one value longer than the DH joints: the refusal
    says the jaw is read from its own topic only (it said to name a jaw topic, and naming
    the joint topic then failed on its 7 values)."""
    from graphtrack.io.topics import TopicSelection
    from graphtrack.track import TrackOptions, _open

    seq = _bag(tmp_path, missing_jaw=range(6), q=(0.1,) * 7)
    with pytest.raises(InputError, match=r"no jaw readings \(no messages on /dvrk/PSM1/state_jaw_current.*"
                                         r"state_joint_current hold 7 values for robot\.json's 6 DH joints: a jaw "
                                         r"recorded as the joint message's last value is not read"):
        _open(seq, TrackOptions(), True, TopicSelection())
    with pytest.raises(InputError, match=r"no messages on /dvrk/PSM1/state_jaw_current; name the jaw topic "
                                         r"with --jaw-topic\); the tool tip"):   # 6 values: no such note
        _open(_bag(tmp_path / "six", missing_jaw=range(6)), TrackOptions(), True, TopicSelection())


def test_codec_messages_stay_off_the_terminal(tmp_path):
    """Damaged PNG / JPEG, a link to nothing and a float TIFF: read in a fresh process whose
    stderr is captured; OpenCV's imread is the oracle that the damaged files do not decode."""
    im = np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "ok.png"), im)
    cv2.imwrite(str(tmp_path / "ok.jpg"), im)
    for ext in ("png", "jpg"):
        data = (tmp_path / f"ok.{ext}").read_bytes()
        (tmp_path / f"cut.{ext}").write_bytes(data[: len(data) // 2])
    os.symlink(tmp_path / "nothing.png", tmp_path / "dangling.png")
    cv2.imwrite(str(tmp_path / "float.tiff"), np.random.default_rng(1).random((20, 30)).astype(np.float32))
    names = ["ok.png", "ok.jpg", "cut.png", "cut.jpg", "dangling.png", "float.tiff"]
    code = ("import json, sys; from pathlib import Path; from graphtrack.io.decode import read_image_file\n"
            f"d = Path({str(tmp_path)!r}); names = {names!r}\n"
            "print(json.dumps({n: read_image_file(d / n)[1] for n in names}))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stderr == "", p.stderr
    why = json.loads(p.stdout)
    assert why["ok.png"] is None and why["ok.jpg"] is None
    assert cv2.imread(str(tmp_path / "cut.png")) is None and why["cut.png"].startswith("cut.png does not decode")
    assert "PNG" in why["cut.png"] and "WARN" not in why["cut.png"]  # the library's words are the reason
    assert why["cut.jpg"].startswith("cut.jpg does not decode")
    assert why["dangling.png"] == "dangling.png is missing (a link to nothing)"
    # libtiff's complaint is the reason exactly when OpenCV itself cannot read the file
    assert (why["float.tiff"] is None) == (cv2.imread(str(tmp_path / "float.tiff")) is not None)


def test_a_harmless_jpeg_warning_keeps_the_image_and_threads_keep_stderr(tmp_path):
    """libjpeg warns of extraneous bytes before a marker (many MJPEG cameras) but decodes
    the image intact: it is kept, equal to cv2.imdecode's; four threads decoding damaged
    and good images at once leave fd 2 as it was; a decode that raises restores it."""
    code = r"""
import os, sys, threading, cv2, numpy as np
from graphtrack.io import decode
img = (np.random.default_rng(0).random((64, 64, 3)) * 255).astype(np.uint8)
enc = cv2.imencode(".jpg", img)[1].tobytes()
i = enc.index(b"\xff\xc4")
extra = enc[:i] + b"\x12\x34" + enc[i:]
im, msg = decode.decode_bytes(extra)
with decode.library_messages():   # the oracle prints the same warning
    ref = cv2.imdecode(np.frombuffer(extra, np.uint8), cv2.IMREAD_COLOR)
assert im is not None and np.array_equal(im, ref) and "extraneous" in msg, msg
png = cv2.imencode(".png", img)[1].tobytes()
def work():
    for _ in range(30):
        assert decode.decode_bytes(png[: len(png) // 2])[0] is None
        assert decode.decode_bytes(png)[0] is not None
ts = [threading.Thread(target=work) for _ in range(4)]
[t.start() for t in ts]; [t.join() for t in ts]
try:
    with decode.library_messages():
        raise KeyError("boom")
except KeyError:
    pass
os.write(2, b"fd 2 restored\n")
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stderr == "fd 2 restored\n", p.stderr


def test_compare_recomputes_a_cell_whose_recording_changed(folder_rec, tmp_path, capsys):
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(folder_rec, rec)
    args = ["compare", rec, "--out", tmp_path / "study", "--estimators", "kinematics"]

    def ran() -> str:
        code = main([str(a) for a in args])
        assert code == 0
        return next(ln for ln in capsys.readouterr().out.splitlines() if "cells computed" in ln)

    assert ran().startswith("1 cells computed, 0 reused")
    assert ran().startswith("0 cells computed, 1 reused")       # nothing changed: reused
    assert main(["track", str(rec), "--out", str(rec / "run"), "--estimator", "kinematics", "--quiet"]) == 0
    capsys.readouterr()
    assert ran().startswith("0 cells computed, 1 reused")       # a run's output inside it is not the recording
    inside = ["compare", rec, "--out", rec / "study", "--estimators", "kinematics"]
    assert main([str(a) for a in inside]) == 0                    # the study inside the recording it reads
    assert "| kinematics | missing" not in (rec / "study" / "table.md").read_text()
    assert main([str(a) for a in inside]) == 0
    assert "0 cells computed, 1 reused" in capsys.readouterr().out
    # a done.json from before other folders were left out of the fingerprint: still reused
    done = next((rec / "study" / "runs").glob("*/kinematics/done.json"))
    doc = json.loads(done.read_text())
    doc["recording"]["run/"] = [4, 1234, 99]
    done.write_text(json.dumps(doc))
    assert main([str(a) for a in inside]) == 0
    assert "0 cells computed, 1 reused" in capsys.readouterr().out
    joints = (rec / "joints.csv").read_text().splitlines()
    head, row = joints[0], joints[1].split(",")
    row[2] = repr(float(row[2]) + 0.01)                           # one joint reading edited in place
    (rec / "joints.csv").write_text("\n".join([head, ",".join(row)] + joints[2:]) + "\n")
    assert ran().startswith("1 cells computed, 0 reused")
    code, err = run_cli(["compare", rec, rec, "--out", tmp_path / "s2"], capsys)
    assert code == 2 and "given twice" in error_line(err)


def test_calibration_stereo_keys_and_distortion_models(tmp_path):
    import yaml

    from graphtrack.geometry.camera import load_calibration

    base = {"ImageSize": [48, 64], "K1": [50.0, 0, 32, 0, 50.0, 24, 0, 0, 1], "D1": [0.1, 0.01, 0, 0, 0],
            "D2": [0, 0, 0, 0, 0], "R": [1, 0, 0, 0, 1, 0, 0, 0, 1], "T": [-5.0, 0, 0]}
    path = tmp_path / "camera_calibration.yaml"
    path.write_text(yaml.safe_dump(base))                          # D2, R, T without K2
    with pytest.raises(InputError, match="missing key 'K2'"):
        load_calibration(path)
    mono = {k: base[k] for k in ("ImageSize", "K1")}
    for D, ok in (([0.1, 0.01, 0, 0], True), ([0.1, 0.01, 0, 0, 0.001, 0, 0, 0], True),
                  ([0.1, 0.01, 0, 0, 0.001, 0.2, 0, 0], False), ([0.1] * 12, False)):
        path.write_text(yaml.safe_dump({**mono, "D1": D}))
        if ok:   # OpenCV's model with the same coefficients is the oracle for the first five
            np.testing.assert_array_equal(load_calibration(path).left.dist, (D + [0.0])[:5])
        else:
            with pytest.raises(InputError, match="k4 k5 k6|expected 4, 5 or 8"):
                load_calibration(path)


def test_robot_point_features_are_unique_and_at_most_64_and_tip_feature_is_never_ignored(folder_rec, tmp_path, capsys):
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(folder_rec, rec)
    doc = json.loads((rec / "robot.json").read_text())
    code, err = run_cli(["track", rec, "--out", tmp_path / "o", "--estimator", "kinematics", "--quiet",
                         "--tip-feature", ""], capsys)
    assert code == 2 and "--tip-feature" in error_line(err) and "no point feature ''" in error_line(err)
    doc["point_features"][1]["name"] = doc["point_features"][0]["name"]
    (rec / "robot.json").write_text(json.dumps(doc))
    code, err = run_cli(["track", rec, "--out", tmp_path / "o", "--estimator", "kinematics", "--quiet"], capsys)
    assert code == 2 and "point_features[1]: name" in error_line(err)
    from graphtrack.robot.description import MAX_POINT_FEATURES

    doc["point_features"] = [{**doc["point_features"][0], "name": f"m{i}"} for i in range(MAX_POINT_FEATURES + 1)]
    (rec / "robot.json").write_text(json.dumps(doc))
    code, err = run_cli(["track", rec, "--out", tmp_path / "o", "--estimator", "kinematics", "--quiet"], capsys)
    assert code == 2 and f"point_features: {MAX_POINT_FEATURES + 1} entries; at most 64" in error_line(err)


def test_detect_refuses_another_runs_files_and_a_folder_in_their_place(folder_rec, tmp_path, capsys):
    out = tmp_path / "d"
    args = ["detect", folder_rec, "--out", out, "--quiet", "--max-frames", "1"]
    assert run_cli(args, capsys)[0] == 0
    code, err = run_cli(args, capsys)
    assert code == 2 and "holds another run's files (detections.csv)" in error_line(err)
    assert run_cli(args + ["--overwrite"], capsys)[0] == 0
    blocked = tmp_path / "b"
    (blocked / "detections.csv").mkdir(parents=True)
    code, err = run_cli(["detect", folder_rec, "--out", blocked, "--quiet", "--overwrite"], capsys)
    assert code == 2 and "detections.csv: cannot remove" in error_line(err)


def test_an_error_starts_on_its_own_line_after_a_progress_bar(folder_rec, tmp_path):
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(folder_rec, rec)
    shutil.rmtree(rec / "frames")
    (rec / "video.mp4").write_text("not a video")
    p = subprocess.run([sys.executable, "-m", "graphtrack.cli", "track", str(rec), "--out", str(tmp_path / "o"),
                        "--estimator", "kinematics"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 2
    lines = p.stderr.splitlines()
    assert lines[-1].startswith("graphtrack: error: ") and "video.mp4" in lines[-1], p.stderr


def test_options_the_chosen_estimator_does_not_take_are_named(tmp_path, capsys):
    from graphtrack.cli import build_parser
    from graphtrack.commands.track import unused_options

    def lines(*argv):
        return unused_options(build_parser().parse_args(["track", "SEQ", "--out", str(tmp_path), *argv]))

    assert lines("--estimator", "pf", "--lag", "2") == [
        "warning: --lag applies to smoother, not to pf: ignored"]
    assert lines("--estimator", "batch", "--particles", "50", "--no-search") == [
        "warning: --particles applies to pf, not to batch: ignored",
        "warning: --no-search applies to pf and smoother, not to batch: ignored"]
    assert lines("--estimator", "smoother", "--lag", "2", "--no-edge-bias") == []


def test_recording_warnings_are_kept_in_metrics_when_quiet(folder_rec, tmp_path, capsys):
    import shutil

    import yaml

    from graphtrack.track import MAX_WARNINGS, capped

    rec = tmp_path / "rec"
    shutil.copytree(folder_rec, rec)
    doc = yaml.safe_load((rec / "camera_calibration.yaml").read_text())
    K = doc["K1"]["data"] if isinstance(doc["K1"], dict) else doc["K1"]
    K[2], K[5] = 2 * K[2], 2 * K[5]                        # the principal point of a 2x larger image
    (rec / "camera_calibration.yaml").write_text(yaml.safe_dump(doc))
    code, err = run_cli(["track", rec, "--out", tmp_path / "o", "--estimator", "kinematics", "--quiet"], capsys)
    assert code == 0 and err == ""
    kept = json.loads((tmp_path / "o" / "metrics.json").read_text())["recording_warnings"]
    assert "K1's principal point" in kept[0]
    # the tip it puts outside the image in every frame is warned about, and kept, too
    assert len(kept) == 2 and "tool tip projects outside the image in every tracked frame" in kept[1]
    code, out = run_cli(["compare", rec, "--out", tmp_path / "s", "--estimators", "kinematics", "--quiet"], capsys)
    assert code == 0 and f"- {kept[0]}" in (tmp_path / "s" / "table.md").read_text()   # a study's cells run quietly
    lines = [str(i) for i in range(MAX_WARNINGS + 5)]
    assert capped(lines) == lines[:MAX_WARNINGS] + ["... and 5 more"] and capped(lines[:3]) == lines[:3]
