"""Inputs that parse but cannot be right, each through the CLI (``graphtrack.cli.main``)
with the catalogue's rules (test_hardening_catalogue): a hand-eye in metres or inverted,
a stereo baseline in metres, a truth.csv with unusable poses, options that do not go
together, an empty output path, a run or study in which nothing was tracked, a damaged
video; and a robot without a shaft, which tracks from its markers."""
from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from test_hardening_catalogue import (REPO, assert_outputs_sane, base, check_exit2, copy, edit_joints,  # noqa: F401
                                      edit_json, edit_yaml, error_line, run_cli, set_column, track)
from test_hardening_extra import stereo  # noqa: F401


def scale_tvec(f: float):
    def fn(doc):
        doc["PSM1_tvec"] = [f * v for v in doc["PSM1_tvec"]]
    return fn


def shift_tvec_x(mm: float):
    """The camera's x moved by ``mm``: the tool in front of it, far outside its image."""
    def fn(doc):
        doc["PSM1_tvec"][0] += mm
    return fn


def invert_handeye(doc):
    """base-from-camera written where camera-from-base belongs."""
    R = cv2.Rodrigues(np.asarray(doc["PSM1_rvec"], float))[0]
    t = np.asarray(doc["PSM1_tvec"], float)
    doc["PSM1_rvec"] = cv2.Rodrigues(R.T)[0].ravel().tolist()
    doc["PSM1_tvec"] = (-R.T @ t).tolist()


def truth_field(line: int, col: slice, values: list[str]):
    def mutate(rec):
        lines = (rec / "truth.csv").read_text().splitlines()
        row = lines[line - 1].split(",")
        row[col] = values
        lines[line - 1] = ",".join(row)
        (rec / "truth.csv").write_text("\n".join(lines) + "\n")
    return mutate


KIN = ("--estimator", "kinematics")
EXIT2 = [
    ("handeye_in_metres", "folder", lambda r: edit_yaml(r / "handeye.yaml", scale_tvec(1e-3)), KIN,
     r"handeye\.yaml: key 'PSM1_tvec' puts the camera 0\.\d+ mm from the arm's base.*multiplied by 1000"),
    ("handeye_zero", "folder",
     lambda r: edit_yaml(r / "handeye.yaml", lambda d: d.update(PSM1_tvec=[0, 0, 0], PSM1_rvec=[0, 0, 0])), KIN,
     r"handeye\.yaml: key 'PSM1_tvec' puts the camera 0 mm"),
    ("handeye_inverted", "folder", lambda r: edit_yaml(r / "handeye.yaml", invert_handeye), KIN,
     r"handeye\.yaml: at this hand-eye the tool tip is behind the camera in all 12 tracked frames"),
    ("handeye_off_image", "folder", lambda r: edit_yaml(r / "handeye.yaml", shift_tvec_x(300.0)),
     ("--estimator", "smoother"),
     r"handeye\.yaml: at this hand-eye the tool tip projects more than an image diagonal outside the image "
     r"in all 12 tracked frames"),
    ("truth_nan_tx", "folder", truth_field(4, slice(2, 3), ["nan"]), KIN,
     r"truth\.csv: line 4 \(frame 2\): tx\.\.qw must be finite with a unit quaternion"),
    ("truth_zero_quaternion", "folder", truth_field(6, slice(5, 9), ["0"] * 4), KIN,
     r"truth\.csv: line 6 \(frame 4\): .*unit quaternion"),
    ("canny_with_weights", "folder", lambda r: (r / "w.pt").write_bytes(b"x"),
     ("--detector", "canny", "--weights", "w.pt"), r"--weights w\.pt: the canny detector has no weights"),
]


@pytest.mark.parametrize("case", EXIT2, ids=[c[0] for c in EXIT2])
def test_plausibility_exit2(case, base, tmp_path, capsys):  # noqa: F811
    check_exit2(case, base, tmp_path, capsys)


def test_truth_rows_of_unknown_pose_are_not_scored(base, tmp_path, capsys):  # noqa: F811
    """A truth.csv row with all of tx..qw empty is a pose not known: the run goes on, and
    that frame has no pose error while the others do."""
    rec = copy(base, "folder", tmp_path)
    truth_field(5, slice(2, 9), [""] * 7)(rec)
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, *KIN)
    assert code == 0, err
    rows = (out / "truth_errors.csv").read_text().splitlines()[1:]
    trans = {int(r.split(",")[0]): float(r.split(",")[1]) for r in rows}
    assert math.isnan(trans[3]) and all(math.isfinite(v) for k, v in trans.items() if k != 3)


def test_bad_truth_is_refused_before_the_run(base, tmp_path, capsys):  # noqa: F811
    rec = copy(base, "folder", tmp_path)
    truth_field(3, slice(2, 3), ["nan"])(rec)
    code, err = track(rec, tmp_path / "out", capsys, *KIN)
    assert code == 2 and "truth.csv" in error_line(err)
    assert not (tmp_path / "out" / "trajectory.csv").exists()


def test_tip_outside_the_image_in_every_frame_is_warned(base, tmp_path, capsys):  # noqa: F811
    """The camera turned 40 deg about its y axis: the tip stays in front of it and, by
    OpenCV's projection of the robot's tip (oracle), right of the image in every frame;
    the run warns and counts 12 frames in front, none inside."""
    from graphtrack.robot.description import load_robot_json
    from graphtrack.robot.features import base_features

    rec = copy(base, "folder", tmp_path)
    Ry = cv2.Rodrigues(np.array([0.0, np.radians(40.0), 0.0]))[0]

    def turn(doc):
        R = Ry @ cv2.Rodrigues(np.asarray(doc["PSM1_rvec"], float))[0]
        doc["PSM1_rvec"] = cv2.Rodrigues(R)[0].ravel().tolist()
        doc["PSM1_tvec"] = (Ry @ np.asarray(doc["PSM1_tvec"], float)).tolist()
    edit_yaml(rec / "handeye.yaml", turn)
    he = yaml.safe_load((rec / "handeye.yaml").read_text())
    cal = yaml.safe_load((rec / "camera_calibration.yaml").read_text())
    K, D = (np.asarray(cal[k]["data"] if isinstance(cal[k], dict) else cal[k], float) for k in ("K1", "D1"))
    q = np.loadtxt(rec / "joints.csv", delimiter=",", skiprows=1)[:, 2:]
    tips = base_features(load_robot_json(rec / "robot.json"), q).tip
    rvec, tvec = np.asarray(he["PSM1_rvec"], float), np.asarray(he["PSM1_tvec"], float) / 1000.0
    assert np.all((cv2.Rodrigues(rvec)[0] @ tips.T)[2] + tvec[2] > 0)
    uv = cv2.projectPoints(tips, rvec, tvec, K.reshape(3, 3), D)[0].reshape(-1, 2)
    assert np.all(uv[:, 0] > cal["ImageSize"][1])
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, *KIN, quiet=False)
    assert code == 0, err
    assert "the tool tip projects outside the image in every tracked frame" in err
    doc = json.loads((out / "metrics.json").read_text())
    assert (doc["frames_tip_in_front"], doc["frames_tip_in_image"]) == (12, 0)


@pytest.mark.parametrize("T", [[0.0, 0.0, 0.0], [-0.005, 0.0, 0.0]], ids=["zero", "metres"])
def test_stereo_baseline_in_metres_or_none(T, stereo, tmp_path, capsys):  # noqa: F811
    rec = copy(stereo.parent, stereo.name, tmp_path)
    edit_yaml(rec / "camera_calibration.yaml", lambda d: d.update(T=T))
    code, err = track(rec, tmp_path / "out", capsys, *KIN)
    assert code == 2, err
    assert re.search(r"camera_calibration\.yaml: key 'T' is 0(\.005)? mm long; .*0\.5 to 1000 mm",
                     error_line(err))


@pytest.mark.parametrize("command", [["track"], ["detect"], ["simulate"], ["compare"]])
def test_empty_output_path(command, base, tmp_path, capsys):  # noqa: F811
    args = [*command, ""] if command == ["simulate"] else [*command, base / "folder", "--out", " "]
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        with pytest.raises(SystemExit) as e:
            run_cli(args, capsys)
    finally:
        os.chdir(cwd)
    assert e.value.code == 2
    assert "an empty path would mean the current folder" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_detect_with_no_readable_frame(base, tmp_path, capsys):  # noqa: F811
    rec = copy(base, "folder", tmp_path)
    for p in (rec / "frames").iterdir():
        p.write_bytes(b"not an image")
    code, err = run_cli(["detect", rec, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2
    assert re.search(r"no frame could be detected on: 12 of 12 frames skipped \(corrupt_image: 12\); "
                     r"first: frame 0: ", error_line(err)), err


def test_detect_names_why_frames_were_skipped(base, tmp_path, capsys):  # noqa: F811
    """Half the frames of another size: detect says which reason and which frame, as track does."""
    from graphtrack.cli import main

    rec = copy(base, "folder", tmp_path)
    for p in sorted((rec / "frames").iterdir())[6:]:
        img = cv2.imread(str(p))
        cv2.imwrite(str(p), cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2)))
    assert main(["detect", str(rec), "--out", str(tmp_path / "out"), "--detector", "canny"]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"12 frames \(6 skipped: image_size: 6; first: frame 6: image is 240x135 px", printed), printed
    assert len((tmp_path / "out" / "detections.csv").read_text().splitlines()) == 1 + 6


def test_compare_with_a_failed_cell(base, tmp_path, capsys):  # noqa: F811
    """A recording whose every frame is skipped, and one whose tool is behind the camera
    throughout, fail their cells; the other is tabled, and the study exits 2 naming the count."""
    bad = copy(base, "folder", tmp_path)
    edit_joints(bad, set_column(4, "nan"))
    inverted = tmp_path / "inverted"
    copy(base, "folder", tmp_path / "x").rename(inverted)
    edit_yaml(inverted / "handeye.yaml", invert_handeye)
    code, err = run_cli(["compare", base / "folder", bad, inverted, "--out", tmp_path / "study", "--estimators",
                         "kinematics", "--observations", "canny", "--workers", "1", "--quiet"], capsys)
    assert code == 2, err
    assert re.search(r"cell rec/.* failed: no frame was tracked", err)
    assert re.search(r"cell inverted/.* failed: .*handeye\.yaml: .*behind the camera", err)
    assert re.search(r"2 cell\(s\) failed", error_line(err))
    assert "folder" in (tmp_path / "study" / "table.md").read_text()


def test_damaged_video_is_one_line(base, tmp_path):  # noqa: F811
    """FFmpeg's own complaints ("moov atom not found") stay off stderr: one line, exit 2."""
    rec = copy(base, "folder", tmp_path)
    for p in (rec / "frames").iterdir():
        p.unlink()
    (rec / "frames").rmdir()
    (rec / "video.mp4").write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}
    p = subprocess.run([sys.executable, "-m", "graphtrack.cli", "track", str(rec), "--out", str(tmp_path / "out"),
                        "--quiet"], capture_output=True, text=True, env=dict(env, PYTHONPATH=str(REPO)), timeout=120)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [error_line(p.stderr)]
    assert "video.mp4: cannot open the video" in p.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())   # nothing to block a rerun


@pytest.mark.parametrize("command", [["track", "--estimator", "smoother"], ["refine"]])
def test_robot_without_shaft_tracks_from_markers(command, base, tmp_path, capsys):  # noqa: F811
    """robot.json without shaft_features: the smoother and the batch run on the markers
    alone (a warning says so), every pose finite."""
    rec = copy(base, "folder", tmp_path)
    edit_json(rec / "robot.json", lambda d: d.pop("shaft_features"))
    out = tmp_path / "out"
    code, err = run_cli([command[0], rec, "--out", out, *command[1:], "--detector", "canny"], capsys)
    assert code == 0, err
    assert "has no shaft_features: tracking from the markers alone" in err
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["frames_tracked"] == 12 and doc["frames_tip_in_front"] == 12
    assert all(math.isfinite(v) for v in (doc["tip_error_px"]["mean"], doc["translation_error_mm"]["mean"]))
    assert any("tracking from the markers alone" in w for w in doc["recording_warnings"])
    assert_outputs_sane(out)
    # the markers are used from the first frame (they were held back 30 frames for a shaft
    # that a tool without shaft features never shows: a 12-frame run stayed at the prior)
    import csv
    with (out / "trajectory.csv").open() as f:
        tx = [r["tx"] for r in csv.DictReader(f)]
    assert len(set(tx)) > 1, "E never moved from handeye.yaml"


@pytest.mark.parametrize("mutate, extra, why", [
    (lambda d: d.update(shaft_features=[], point_features=[]), (), "no point_features"),
    (lambda d: d.pop("shaft_features"), ("--no-markers",), r"its markers are off \(--no-markers\)"),
])
def test_robot_with_nothing_to_observe_is_refused(mutate, extra, why, base, tmp_path, capsys):  # noqa: F811
    """No shaft and no markers to see: an image-based estimator would return the prior with
    exit 0; refused before the run. The kinematics baseline still runs."""
    rec = copy(base, "folder", tmp_path)
    edit_json(rec / "robot.json", mutate)
    code, err = run_cli(["track", rec, "--out", tmp_path / "out", "--quiet", *extra], capsys)
    assert code == 2 and re.search(rf"robot\.json: no shaft_features and {why}: smoother has nothing in the "
                                   r"images to track", error_line(err)), err
    code, err = run_cli(["track", rec, "--out", tmp_path / "kin", "--quiet", "--estimator", "kinematics"], capsys)
    assert code == 0, err


def test_compare_with_a_crashed_cell_is_an_internal_error(base, tmp_path, capsys, monkeypatch):  # noqa: F811
    """A cell that fails by a bug (not bad input) makes the study exit 1, as `track` would,
    and its error.json says so."""
    import graphtrack.study.execute as execute

    def crash(*a, **k):
        raise ZeroDivisionError("division by zero")
    monkeypatch.setattr(execute, "track", crash)
    code, err = run_cli(["compare", base / "folder", "--out", tmp_path / "study", "--estimators", "kinematics",
                         "--observations", "canny", "--workers", "1", "--quiet"], capsys)
    assert code == 1, err
    assert "internal error in 1 cell(s)" in err and "ZeroDivisionError" in err
    (doc,) = [json.loads(p.read_text()) for p in (tmp_path / "study").rglob("error.json")]
    assert doc["internal"] is True and "ZeroDivisionError" in doc["traceback"]


@pytest.mark.parametrize("command", ["track", "detect", "compare"])
def test_out_that_is_the_recording_is_refused(command, base, tmp_path, capsys):  # noqa: F811
    """--out SEQ would put a run's files beside the recording's own (and make compare
    take the recording as changed): refused before anything is written."""
    rec = copy(base, "folder", tmp_path)
    before = sorted(p.name for p in rec.iterdir())
    code, err = run_cli([command, rec, "--out", rec / ".." / rec.name, "--quiet"], capsys)
    assert code == 2 and re.search(r"--out \S+ is the recording folder itself; write the run's files into a "
                                   r"folder of their own, e\.g\. --out \S+/run", error_line(err)), err
    assert sorted(p.name for p in rec.iterdir()) == before
    code, err = run_cli([command, rec, "--out", rec / "frames" / "out", "--quiet"], capsys)
    assert code == 2 and "is inside the recording's frames/" in error_line(err), err


def test_greyscale_frames_warn_that_markers_cannot_be_found(base, tmp_path, capsys):  # noqa: F811
    """Markers are found by colour: greyscale frames track from the shaft alone, said once
    (and kept in metrics.json)."""
    from graphtrack.cli import main

    rec = copy(base, "folder", tmp_path)
    for p in (rec / "frames").iterdir():
        cv2.imwrite(str(p), cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2GRAY))
    out = tmp_path / "out"
    assert main(["track", str(rec), "--out", str(out), "--max-frames", "3"]) == 0
    err = capsys.readouterr().err
    assert err.count("the frames are greyscale: painted markers are found by their colour") == 1, err
    doc = json.loads((out / "metrics.json").read_text())
    assert any("greyscale" in w for w in doc["recording_warnings"])
    assert main(["track", str(rec), "--out", str(tmp_path / "nm"), "--max-frames", "3", "--no-markers"]) == 0
    assert "greyscale" not in capsys.readouterr().err


def test_a_black_first_frame_is_not_taken_for_greyscale(base, tmp_path, capsys):  # noqa: F811
    """The light off in frame 0 (all black): the colour frames after it decide; no warning."""
    from graphtrack.cli import main

    rec = copy(base, "folder", tmp_path)
    first = rec / "frames" / "000000.png"
    cv2.imwrite(str(first), np.zeros_like(cv2.imread(str(first))))
    assert main(["track", str(rec), "--out", str(tmp_path / "out"), "--max-frames", "3"]) == 0
    assert "greyscale" not in capsys.readouterr().err


def test_greyscale_frames_of_a_robot_with_markers_only_are_refused(base, tmp_path, capsys):  # noqa: F811
    """No shaft, and markers that greyscale frames cannot show: nothing to track (the run
    returned the prior with exit 0)."""
    rec = copy(base, "folder", tmp_path)
    edit_json(rec / "robot.json", lambda d: d.pop("shaft_features"))
    for p in (rec / "frames").iterdir():
        cv2.imwrite(str(p), cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2GRAY))
    code, err = run_cli(["track", rec, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and re.search(r"robot\.json: no shaft_features, and the frames are greyscale \(frame 0\) "
                                   r"while painted markers are found by their colour", error_line(err)), err


def test_detect_on_a_recording_without_frames(base, tmp_path, capsys):  # noqa: F811
    rec = copy(base, "folder", tmp_path)
    (rec / "joints.csv").write_text((rec / "joints.csv").read_text().splitlines()[0] + "\n")
    for p in (rec / "frames").iterdir():
        p.unlink()
    code, err = run_cli(["detect", rec, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and re.search(r"rec/joints\.csv: no rows after the header", error_line(err)), err


@pytest.mark.parametrize("ext", ["png", "jpg"])
def test_a_still_image_named_video_is_refused(ext, base, tmp_path, capsys):  # noqa: F811
    """A PNG or JPEG renamed video.mp4 opens in FFmpeg as a one-frame video: refused by name,
    exit 2, instead of tracking its one frame and warning about the rest."""
    rec = copy(base, "folder", tmp_path)
    first = sorted((rec / "frames").iterdir())[0]
    cv2.imwrite(str(rec / f"still.{ext}"), cv2.imread(str(first)))
    for p in (rec / "frames").iterdir():
        p.unlink()
    (rec / "frames").rmdir()
    (rec / f"still.{ext}").rename(rec / "video.mp4")
    code, err = run_cli(["track", rec, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2, err
    assert re.search(r"video\.mp4: one (PNG|JPEG) image, not a video", error_line(err))
