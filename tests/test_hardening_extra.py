"""Bad inputs beyond issue #21's list, as a hostile user would try them, each through the
CLI (``graphtrack.cli.main``) with the catalogue's rules: exit 2 with one line naming the
file, field, topic or option, or exit 0 with the problem warned about (and counted in
metrics.json where it is per frame); never the internal-error guard, a NaN pose row or
a NaN in metrics.json.
"""
from __future__ import annotations

import errno
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from test_hardening_catalogue import (REPO, assert_outputs_sane, base, check_exit2, copy, edit_joints,  # noqa: F401
                                      edit_yaml, error_line, track, track_with_file_limit)


@pytest.fixture(scope="module")
def stereo(tmp_path_factory):
    """A tiny stereo recording (6 frames, 270x480, folder form: frames_right/, K2, D2, R, T)."""
    from graphtrack.sim.simulate import simulate

    return simulate(tmp_path_factory.mktemp("stereo") / "rec", frames=6, size=(270, 480), form="folder",
                    progress=False, stereo=True)


def drop_topic(topic: str):
    """Rewrite recording.bag without ``topic``'s connection and messages."""
    def mutate(rec):
        from rosbags.rosbag1 import Reader, Writer

        src, dst = rec / "recording.bag", rec / "filtered.tmp"
        with Reader(src) as r, Writer(dst) as w:
            conns = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
                     for c in r.connections if c.topic != topic}
            for c, t, raw in r.messages():
                if c.id in conns:
                    w.write(conns[c.id], t, raw)
        dst.replace(src)
    return mutate


def to_video(rows: int):
    """frames/ -> video.mp4 (all 12 images), joints.csv cut to its first ``rows`` rows."""
    def mutate(rec):
        files = sorted((rec / "frames").iterdir())
        h, w = cv2.imread(str(files[0])).shape[:2]
        vw = cv2.VideoWriter(str(rec / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30, (w, h))
        for p in files:
            vw.write(cv2.imread(str(p)))
            p.unlink()
        vw.release()
        (rec / "frames").rmdir()
        edit_joints(rec, lambda r: r[:rows + 1])
    return mutate


def write(name: str, text: str):
    def mutate(rec):
        (rec / name).write_text(text)
    return mutate


def unlink_all(folder: str):
    def mutate(rec):
        for p in (rec / folder).iterdir():
            p.unlink()
    return mutate


def set_focal(v: float):
    def fn(doc):
        doc["K1"]["data"][0] = doc["K1"]["data"][4] = v
    return fn


def renumber_from_1(rec):
    """frames/000000.png ... 000011.png renamed 000001.png ... 000012.png."""
    for p in sorted((rec / "frames").iterdir(), reverse=True):
        p.rename(p.with_name(f"{int(p.stem) + 1:06d}{p.suffix}"))


def keep(rec):
    pass


# (id, form, mutate(rec), extra track args, regex the one error line must match)
EXIT2 = [
    ("frames_folder_empty", "folder", unlink_all("frames"), (), r"frames: no images"),
    ("joints_csv_empty", "folder", write("joints.csv", ""), (), r"joints\.csv: header must be"),
    ("joints_csv_header_only", "folder", lambda r: edit_joints(r, lambda rows: rows[:1]), (),
     r"joints\.csv: no rows after the header"),
    ("labels_csv_a_folder", "folder", lambda r: (r / "labels.csv").unlink() or (r / "labels.csv").mkdir(), (),
     r"labels\.csv: a folder, not a file"),
    ("frames_numbered_from_1", "folder", renumber_from_1, (),
     r"frames: holds 12 images but joints\.csv has 12 rows \(first image without a row: 000012\.png\).*"
     r"numbered from 1, frames from 0: rename them"),
    ("labels_missing_column", "folder", write("labels.csv", "frame,u\n0,10\n"), (),
     r"labels\.csv: header must be 'frame,u,v', found 'frame,u'"),
    ("robot_json_empty", "folder", write("robot.json", ""), (), r"robot\.json: not valid JSON"),
    ("calibration_not_a_mapping", "folder", write("camera_calibration.yaml", "- 1\n"), (),
     r"camera_calibration\.yaml: expected a mapping"),
    ("focal_below_1px", "folder", lambda r: edit_yaml(r / "camera_calibration.yaml", set_focal(1e-9)), (),
     r"camera_calibration\.yaml: key 'K1': focal lengths 1e-09, 1e-09 px would see more than 168 deg .*"
     r"a K divided by the image size"),
    ("focal_negative", "folder", lambda r: edit_yaml(r / "camera_calibration.yaml", set_focal(-800)), (),
     r"camera_calibration\.yaml: key 'K1': focal lengths must be in \[1, 1e6\] px, got -800, -800"),
    ("video_more_frames_than_rows", "folder", to_video(8), (),
     r"video\.mp4: holds 12 frames but joints\.csv has 8 rows"),
    ("bag_image_topic_missing", "bag", drop_topic("/stereo/left/image"), (),
     r"recording\.bag: no left image topic"),
    ("bag_joint_topic_missing", "bag", drop_topic("/dvrk/PSM1/state_joint_current"), (),
     r"recording\.bag: no messages on the joint topic of PSM1"),
    ("bag_cut_after_100_bytes", "bag",
     lambda r: (r / "recording.bag").write_bytes((r / "recording.bag").read_bytes()[:100]), (),
     r"recording\.bag: bag index unusable.*no complete left image"),
    ("bag_random_bytes", "bag", lambda r: (r / "recording.bag").write_bytes(os.urandom(20000)), (),
     r"recording\.bag: cannot read bag"),
    ("image_topic_override_absent", "bag", keep, ("--image-topic", "/nope"),
     r"recording\.bag: no left image topic \(/nope\)"),
    ("arm_not_recorded", "bag", keep, ("--arm", "PSM2"), r"no messages on the joint topic of PSM2.*--arm PSM1"),
    ("max_frames_0", "folder", keep, ("--max-frames", "0"), r"--max-frames must be a whole number of at least 1"),
    ("seed_negative", "folder", keep, ("--seed", "-1"), r"--seed must be an integer in 0\.\.4294967295"),
    ("lag_nan", "folder", keep, ("--lag", "nan"), r"--lag must be a finite number"),
    ("beta_above_1", "folder", keep, ("--beta", "5"), r"--beta must be in \[0, 1\]"),
    ("alpha_inf", "folder", keep, ("--alpha", "inf"), r"--alpha must be in \(0, 100\] px \(the method's is 10\)"),
    ("alpha_huge", "folder", keep, ("--alpha", "1e9"), r"--alpha must be in \(0, 100\] px"),
    ("particles_0", "folder", keep, ("--estimator", "pf", "--particles", "0"), r"--particles must be a whole number between 1 and 100000, got 0"),
    ("tip_feature_unknown", "folder", keep, ("--tip-feature", "nope"), r"--tip-feature: .*no point feature 'nope'"),
]


@pytest.mark.parametrize("case", EXIT2, ids=[c[0] for c in EXIT2])
def test_extra_exit2(case, base, tmp_path, capsys):  # noqa: F811
    check_exit2(case, base, tmp_path, capsys)


def test_out_is_a_file(base, tmp_path, capsys):  # noqa: F811
    (tmp_path / "f").write_text("")
    code, err = track(base / "folder", tmp_path / "f", capsys)
    assert code == 2 and re.search(r"f: is a file, not a folder \(the output folder\): name a folder", error_line(err))


def test_stereo_right_images_of_another_size_are_counted_and_warned(stereo, tmp_path, capsys):
    rec = copy(stereo.parent, stereo.name, tmp_path)
    for p in (rec / "frames_right").iterdir():
        cv2.imwrite(str(p), cv2.resize(cv2.imread(str(p)), (320, 240)))
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, quiet=False)
    assert code == 0, err
    assert re.search(r"warning: .*6 frames without a usable right image \(image_size 6\)", err), err
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["frames_tracked"] == 6 and doc["frames_left_only"] == 6
    assert doc["right_skipped_reasons"]["image_size"] == 6
    assert_outputs_sane(out)


def test_stereo_without_right_calibration_is_warned(stereo, tmp_path, capsys):
    rec = copy(stereo.parent, stereo.name, tmp_path)
    edit_yaml(rec / "camera_calibration.yaml", lambda d: [d.pop(k) for k in ("K2", "D2", "R", "T")])
    code, err = track(rec, tmp_path / "out", capsys, quiet=False)
    assert code == 0, err
    assert "right images but no K2, D2, R, T" in err and "left image only" in err


def test_stereo_T_nan(stereo, tmp_path, capsys):
    rec = copy(stereo.parent, stereo.name, tmp_path)
    edit_yaml(rec / "camera_calibration.yaml", lambda d: d["T"].__setitem__(0, float("nan")))
    code, err = track(rec, tmp_path / "out", capsys)
    assert code == 2 and re.search(r"camera_calibration\.yaml: key 'T'", error_line(err))


def test_labels_of_frames_the_recording_lacks_are_warned(base, tmp_path, capsys):  # noqa: F811
    rec = copy(base, "folder", tmp_path)
    with (rec / "labels.csv").open("a") as f:
        f.write("999,10,10\n")
    code, err = track(rec, tmp_path / "out", capsys, quiet=False)
    assert code == 0, err
    assert re.search(r"labels\.csv: 1 labels of frames the recording does not have .*frame 999", err), err


def test_full_disk_at_truth_errors_is_one_line(base, tmp_path, capsys, monkeypatch):  # noqa: F811
    """ENOSPC while writing truth_errors.csv (after the trajectory): one line naming it, exit 2,
    and no cut-off file left behind."""
    real_open = Path.open

    def full_disk(self, *a, **kw):
        f = real_open(self, *a, **kw)
        if self.name.startswith("truth_errors.csv"):
            def fail(*_):
                raise OSError(errno.ENOSPC, "No space left on device")
            f.write = fail
        return f

    monkeypatch.setattr(Path, "open", full_disk)
    out = tmp_path / "out"
    code, err = track(base / "folder", out, capsys)
    assert code == 2, err
    assert re.search(r"truth_errors\.csv: cannot write \(No space left on device\)", error_line(err))
    assert not (out / "truth_errors.csv").exists() and not (out / "truth_errors.csv.tmp").exists()
    assert_outputs_sane(out)


def test_full_disk_at_overlay_video_is_one_line(base, tmp_path):  # noqa: F811
    """RLIMIT_FSIZE lets the small text files through but not overlay.mp4: OpenCV's writer
    fails silently, the run must not."""
    out = tmp_path / "out"
    p = track_with_file_limit(base / "folder", out, 20000, "--video")
    assert p.returncode == 2, p.stderr
    assert re.search(r"overlay\.mp4: cannot write the video", error_line(p.stderr))
    assert_outputs_sane(out)


@pytest.mark.parametrize("sig", ["SIGINT", "SIGKILL"])
def test_interrupted_run_leaves_complete_rows(sig, tmp_path):
    """Already right before #21, kept: SIGINT (exit 130) or SIGKILL mid-run leaves trajectory
    files of complete, finite rows."""
    import signal
    import time

    from graphtrack.sim.simulate import simulate

    # 200 frames: the run must outlast the poll below also when the machine is loaded
    rec = simulate(tmp_path / "rec", frames=200, size=(120, 160), form="folder", progress=False)
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    # SIGINT as from a terminal: not ignored in the child, whatever this process inherited
    default_sigint = lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)   # noqa: E731
    p = subprocess.Popen([sys.executable, "-m", "graphtrack.cli", "track", str(rec), "--out", str(out), "--quiet",
                          "--estimator", "pf", "--particles", "20000"], env=env, stderr=subprocess.PIPE, text=True,
                         preexec_fn=default_sigint)
    csv_path, t0 = out / "trajectory.csv", time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < 120:
        if csv_path.is_file() and csv_path.read_text().count("\n") >= 3:   # header + 2 rows
            break
        time.sleep(0.01)
    p.send_signal(getattr(signal, sig))
    err = p.communicate(timeout=60)[1]
    assert "Traceback" not in err and "internal error" not in err, err
    if sig == "SIGINT":
        assert p.returncode == 130 and "interrupted" in err, (p.returncode, signal.getsignal(signal.SIGINT), err)
    else:
        assert p.returncode == -signal.SIGKILL
    assert 3 <= csv_path.read_text().count("\n") < 201
    assert_outputs_sane(out)


def test_ctrl_c_while_the_libraries_load_is_one_line(tmp_path, monkeypatch, capsys):
    """Ctrl-C before the command runs (the commands' imports take a second): exit 130, one
    line, no traceback, and no claim of kept files where no output folder exists."""
    from graphtrack import cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["track", str(tmp_path / "rec"), "--out", str(tmp_path / "out")]) == 130
    assert capsys.readouterr().err == "graphtrack: interrupted\n"


@pytest.mark.parametrize("kind", ["duplicate", "swapped"])
def test_bag_image_stamps_out_of_order_are_counted_and_warned(kind, base, tmp_path, capsys):  # noqa: F811
    """A bag whose image stamps repeat: the repeat is skipped (``stamp_order``), warned about
    and counted. Messages written out of order (each image with its own joints) are read in
    stamp order. Either way trajectory.tum is in time order, without repeats."""
    import dataclasses
    import shutil

    from graphtrack.io.bag_write import write_bag
    from graphtrack.io.recording import open_recording

    frames = [f for f in open_recording(base / "bag").frames()]
    stamps = [f.stamp for f in frames]
    if kind == "duplicate":
        stamps[3] = stamps[2]
    else:
        stamps[2], stamps[3] = stamps[3], stamps[2]
    rec = tmp_path / "rec"
    shutil.copytree(base / "bag", rec)
    (rec / "recording.bag").unlink()
    write_bag(rec / "recording.bag", [dataclasses.replace(f, stamp=s) for f, s in zip(frames, stamps)])
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, quiet=False)
    assert code == 0, err
    doc = json.loads((out / "metrics.json").read_text())
    if kind == "duplicate":
        assert doc["skipped_reasons"] == {"stamp_order": 1} and doc["frames_tracked"] == 5, doc
        assert re.search(r"warning: skipping frame \d: stamp", err), err
    else:
        assert doc["skipped_reasons"] == {} and doc["frames_tracked"] == 6, doc
    tum = [float(ln.split()[0]) for ln in (out / "trajectory.tum").read_text().splitlines()]
    assert tum == sorted(tum) and len(set(tum)) == len(tum)
    assert_outputs_sane(out)
