"""Issue #21's catalogue of bad inputs, each run through the CLI (``graphtrack.cli.main``).

Every case ends either with exit status 2 and one line naming the file, field or
frame, or with exit 0 and the bad frame counted in metrics.json's
``skipped_reasons``. No case may reach the CLI's last-resort guard ("internal
error"), leave a NaN in a pose row or in metrics.json, or exit 0 with no
tracked frame.
"""
from __future__ import annotations

import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from graphtrack.cli import main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """Two tiny simulated recordings (12 frames, 270x480): the folder form and the bag form."""
    from graphtrack.sim.simulate import simulate

    root = tmp_path_factory.mktemp("hardening")
    simulate(root / "folder", frames=12, size=(270, 480), form="folder", progress=False)
    simulate(root / "bag", frames=6, size=(270, 480), form="bag", progress=False)
    return root


def copy(base: Path, form: str, tmp_path: Path) -> Path:
    dst = tmp_path / "rec"
    shutil.copytree(base / form, dst)
    return dst


def run_cli(args, capsys) -> tuple[int, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    return code, err


def track(rec: Path, out: Path, capsys, *extra, quiet=True) -> tuple[int, str]:
    return run_cli(["track", rec, "--out", out, *(["--quiet"] if quiet else []), *extra], capsys)


def error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("graphtrack: error:")]
    assert len(lines) == 1, err
    assert "internal error" not in lines[0], err
    assert "Traceback" not in err, err
    return lines[0]


def assert_outputs_sane(out: Path):
    """Whatever was written: no NaN pose, complete lines, strict JSON."""
    csv_path = out / "trajectory.csv"
    if csv_path.is_file():
        text = csv_path.read_text()
        assert text.endswith("\n")
        rows = list(csv.reader(text.splitlines()))
        for row in rows[1:]:
            pose = [float(v) for v in row[1:9]]
            assert all(math.isfinite(v) for v in pose), row
        stamps = [float(r[1]) for r in rows[1:]]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    tum = out / "trajectory.tum"
    if tum.is_file() and tum.stat().st_size:
        assert tum.read_text().endswith("\n")
    m = out / "metrics.json"
    if m.is_file():
        json.loads(m.read_text(), parse_constant=lambda c: pytest.fail(f"metrics.json holds {c}"))


# -- mutations -----------------------------------------------------------------------------
def edit_json(path: Path, fn):
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def edit_yaml(path: Path, fn):
    doc = yaml.safe_load(path.read_text())
    fn(doc)
    path.write_text(yaml.safe_dump(doc))


def edit_joints(rec: Path, fn):
    rows = list(csv.reader((rec / "joints.csv").read_text().splitlines()))
    rows = fn(rows)
    (rec / "joints.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")


def set_column(col: int, value: str):
    def fn(rows):
        for r in rows[1:]:
            r[col] = value
        return rows
    return fn


def drop_q(rows):  # 5 joints in every row (header q1..q5)
    return [r[:7] + r[8:] if i else r[:7] + [r[-1]] for i, r in enumerate(rows)]


def add_q(rows):  # 7 joints in every row (header q1..q7)
    return [r[:8] + (["q7"] if i == 0 else ["0.1"]) + r[8:] for i, r in enumerate(rows)]


def to_degrees(rows):  # the revolute joints (q1, q2, q4, q5, q6) and the jaw in degrees
    for r in rows[1:]:
        for c in (2, 3, 5, 6, 7, 8):
            r[c] = repr(math.degrees(float(r[c])))
    return rows


def swap_stamps(rows):
    rows[4][1], rows[5][1] = rows[5][1], rows[4][1]
    return rows


def dup_stamp(rows):
    rows[5][1] = rows[4][1]
    return rows


def add_dh_row(doc):
    doc["DH_params"].append(dict(doc["DH_params"][-1]))


def set_label(line: int, u: str):
    def mutate(rec):
        rows = (rec / "labels.csv").read_text().splitlines()
        f, _, v = rows[line - 1].split(",")
        rows[line - 1] = f"{f},{u},{v}"
        (rec / "labels.csv").write_text("\n".join(rows) + "\n")
    return mutate


def resize_frames(h: int, w: int):
    def mutate(rec):
        import cv2

        for p in (rec / "frames").iterdir():
            cv2.imwrite(str(p), cv2.resize(cv2.imread(str(p)), (w, h)))
    return mutate


def non_utf8(name: str):
    def mutate(rec):
        p = rec / name
        p.write_bytes(p.read_bytes() + b"\n# \xff\xfe\xc3\x28\n")
    return mutate


def set_K(i: int, value):
    def fn(doc):
        doc["K1"]["data"][i] = value
    return fn


# (id, form, mutate(rec), extra track args, expected exit, regex the one error line must match)
EXIT2 = [
    ("point_features_ints", "folder", lambda r: edit_json(r / "robot.json", lambda d: d.update(point_features=[1, 2])),
     (), r"robot\.json: point_features\[0\]: expected an object"),
    ("point_features_dict", "folder",
     lambda r: edit_json(r / "robot.json", lambda d: d.update(point_features={"m": d["point_features"][0]})),
     (), r"robot\.json: point_features: expected a list"),
    ("joint_limits_strings", "folder",
     lambda r: edit_json(r / "robot.json", lambda d: d.update(joint_limits=[["a", "b"]] * 7)),
     (), r"robot\.json: joint_limits"),
    ("link_infinity", "folder",
     lambda r: (r / "robot.json").write_text(re.sub(r'"link": 7', '"link": Infinity',
                                                    (r / "robot.json").read_text(), count=1)),
     (), r"robot\.json: tool_tip: link: expected int, got inf"),
    *[(f"non_utf8_{n}", "folder", non_utf8(n), (), rf"{re.escape(n)}: not UTF-8 text")
      for n in ("robot.json", "camera_calibration.yaml", "handeye.yaml", "joints.csv", "labels.csv")],
    ("pf_without_shaft_features", "folder",
     lambda r: edit_json(r / "robot.json", lambda d: d.pop("shaft_features")),
     ("--estimator", "pf", "--particles", "50"), r"\S+/robot\.json: no shaft_features: the particle filter needs"),
    ("handeye_tvec_1e30", "folder",
     lambda r: edit_yaml(r / "handeye.yaml", lambda d: d.update(PSM1_tvec=[1e30, 0.0, 0.0])),
     ("--estimator", "smoother", "--detector", "canny"), r"handeye\.yaml: key 'PSM1_tvec'"),
    ("handeye_rvec_-1e308", "folder",
     lambda r: edit_yaml(r / "handeye.yaml", lambda d: d.update(PSM1_rvec=[-1e308, 0.0, 0.0])),
     (), r"handeye\.yaml: key 'PSM1_rvec'"),
    # nothing tracked: an error naming the reason, never exit 0
    ("image_size_other", "folder", resize_frames(240, 320), (),
     r"no frame was tracked: 12 of 12 frames skipped \(image_size: 12\).*frame 0"),
    ("imagesize_swapped", "folder",
     lambda r: (edit_yaml(r / "camera_calibration.yaml", lambda d: d.update(ImageSize=[480, 270])),
                (r / "labels.csv").unlink()),   # (with labels.csv: the next case)
     (), r"no frame was tracked.*image_size.*ImageSize says 270x480 \(width and height swapped there\?\)"),
    ("imagesize_swapped_labels", "folder",
     lambda r: edit_yaml(r / "camera_calibration.yaml", lambda d: d.update(ImageSize=[480, 270])),
     (), r"labels\.csv: line \d+: .*outside the 270x480 image \(ImageSize in .*camera_calibration\.yaml\); "
         r"it lies inside a 480x270 image: are width and height swapped"),
    ("imagesize_1e9", "folder",
     lambda r: edit_yaml(r / "camera_calibration.yaml", lambda d: d.update(ImageSize=[int(1e9), 480])),
     (), r"camera_calibration\.yaml: ImageSize"),
    ("dh_7_rows_folder", "folder", lambda r: edit_json(r / "robot.json", add_dh_row), (),
     r"joints\.csv: .*6 joints.*robot\.json.*7"),
    ("dh_7_rows_bag", "bag", lambda r: edit_json(r / "robot.json", add_dh_row), (),
     r"no frame was tracked.*joint_count"),
    ("joints_5_per_row", "folder", lambda r: edit_joints(r, drop_q), (), r"joints\.csv: .*5 joints.*robot\.json.*6"),
    ("joints_7_per_row", "folder", lambda r: edit_joints(r, add_q), (), r"joints\.csv: .*7 joints.*robot\.json.*6"),
    ("nan_column", "folder", lambda r: edit_joints(r, set_column(4, "nan")), (), r"no frame was tracked.*nan_joints"),
    # silent wrong output before
    ("joints_in_degrees", "folder", lambda r: edit_joints(r, to_degrees), (),
     r"joints\.csv: 12 of 12 rows hold readings no arm makes in radians and metres \(first: frame 0, q\d = "
     r".* beyond a full turn .*radians \(degrees\?\)\)"),
    ("joints_fewer_rows_than_images", "folder", lambda r: edit_joints(r, lambda rows: rows[:-2]), (),
     r"frames.*12 images.*joints\.csv.*10 rows"),
    ("stamps_in_nanoseconds", "folder",
     lambda r: edit_joints(r, lambda rows: [rows[0]] + [x[:1] + [repr(float(x[1]) * 1e9)] + x[2:] for x in rows[1:]]),
     (), r"joints\.csv: the stamps are 3\.333\d*e\+07 apart \(median\); stamps are seconds.*nanoseconds\?"),
    ("unsorted_stamps", "folder", lambda r: edit_joints(r, swap_stamps), (), r"joints\.csv: line 6: stamp .* not after"),
    ("duplicate_stamps", "folder", lambda r: edit_joints(r, dup_stamp), (), r"joints\.csv: line 6: stamp .* not after"),
    ("empty_stamps", "folder", lambda r: edit_joints(r, set_column(1, "")), (), r"joints\.csv: line 2: stamp"),
    ("decimal_comma", "folder", lambda r: edit_joints(r, set_column(4, '"0,5"')), (),
     r"joints\.csv: line 2: q3 '0,5' is not a number \(a decimal comma\? write 0\.5, not 0,5\)"),
    ("decimal_comma_unquoted", "folder", lambda r: edit_joints(r, set_column(4, "0,5")), (),
     r"joints\.csv: line 2 has 10 fields, expected 9 \(a decimal comma\? write 0\.5, not 0,5\)"),
    ("underscore_number", "folder", lambda r: edit_joints(r, set_column(3, "1_0.5")), (),
     r"joints\.csv: line 2: q2 '1_0\.5' is not a number"),
    ("fullwidth_digit", "folder", lambda r: edit_joints(r, set_column(2, "\uff10.1")), (),
     r"joints\.csv: line 2: q1 '\uff10\.1' is not a number"),
    ("iso_date_stamps", "folder", lambda r: edit_joints(r, set_column(1, "2026-11-29T10:00:00")), (),
     r"joints\.csv: line 2: stamp '2026-11-29T10:00:00' is not a number \(stamps are seconds"),
    ("frame_as_float", "folder", lambda r: edit_joints(r, lambda rows: [rows[0]] + [[f"{i}.0"] + x[1:]
                                                                           for i, x in enumerate(rows[1:])]), (),
     r"joints\.csv: line 2: frame '0\.0' is not a whole number"),
    ("label_out_of_range", "folder", set_label(3, "5000"), (), r"labels\.csv: line 3: .*outside"),
    ("label_nan", "folder", set_label(3, "nan"), (), r"labels\.csv: line 3: .*finite"),
    ("label_1e300", "folder", set_label(3, "1e300"), (), r"labels\.csv: line 3: .*outside"),
    ("K1_22_zero", "folder", lambda r: edit_yaml(r / "camera_calibration.yaml", set_K(8, 0.0)), (),
     r"camera_calibration\.yaml: key 'K1'"),
    ("K1_nested", "folder",
     lambda r: edit_yaml(r / "camera_calibration.yaml",
                         lambda d: d["K1"].update(data=np.reshape(d["K1"]["data"], (3, 3)).tolist())),
     (), r"camera_calibration\.yaml: key 'K1'.*flat list"),
    ("imagesize_fractional", "folder",
     lambda r: edit_yaml(r / "camera_calibration.yaml", lambda d: d.update(ImageSize=[270.5, 480])),
     (), r"camera_calibration\.yaml: ImageSize"),
    ("alpha_string", "folder",
     lambda r: edit_json(r / "robot.json", lambda d: d["DH_params"][0].update(alpha="1.57")),
     (), r"robot\.json: joint 1: alpha: expected float"),
]


def check_exit2(case, base, tmp_path, capsys):
    """Run one (name, form, mutate, extra args, message pattern) case through the CLI: exit 2,
    one error line matching the pattern, and no half-written output."""
    name, form, mutate, extra, pattern = case
    rec = copy(base, form, tmp_path)
    mutate(rec)
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, *extra)
    line = error_line(err)
    assert code == 2, err
    assert re.search(pattern, line), line
    assert_outputs_sane(out)


@pytest.mark.parametrize("case", EXIT2, ids=[c[0] for c in EXIT2])
def test_catalogue_exit2(case, base, tmp_path, capsys):
    check_exit2(case, base, tmp_path, capsys)


def test_nothing_tracked_writes_strict_metrics(base, tmp_path, capsys):
    rec = copy(base, "folder", tmp_path)
    edit_joints(rec, set_column(4, "nan"))
    code, err = track(rec, tmp_path / "out", capsys)
    assert code == 2
    doc = json.loads((tmp_path / "out" / "metrics.json").read_text(), parse_constant=pytest.fail)
    assert doc["frames_tracked"] == 0 and doc["skipped_reasons"] == {"nan_joints": 12}
    assert doc["fps_steady"] is None and doc["tip_error_px"]["mean"] is None


@pytest.mark.parametrize("width", ["sixteen", -4, 10 ** 6, 16.5, True])
def test_weights_metadata_width(width, base, tmp_path, capsys):
    import torch

    from graphtrack.detect.learned import DEFAULT_WEIGHTS

    obj = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    sd = obj["state_dict"] if "state_dict" in obj else obj
    w = tmp_path / "w.pt"
    torch.save({"state_dict": sd, "arch": "linenet-v1", "width": width}, w)
    code, err = track(base / "folder", tmp_path / "out", capsys, "--estimator", "smoother",
                      "--detector", "learned", "--weights", w, "--max-frames", "2")
    assert code == 2
    assert re.search(r"w\.pt: metadata 'width'", error_line(err))


def test_zeroed_jpeg_is_a_counted_skip(base, tmp_path, capsys):
    import cv2

    rec = copy(base, "folder", tmp_path)
    for p in sorted((rec / "frames").iterdir()):
        cv2.imwrite(str(p.with_suffix(".jpg")), cv2.imread(str(p)))
        p.unlink()
    jpg = rec / "frames" / "000003.jpg"
    data = bytearray(jpg.read_bytes())
    start = data.find(b"\xff\xda")          # start of scan: zero the entropy-coded data
    data[start + 20:-2] = bytes(len(data) - start - 22)
    jpg.write_bytes(bytes(data))
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, quiet=False)
    assert code == 0, err
    assert "frame 3" in err and "warning" in err
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["frames_tracked"] == 11 and sum(doc["skipped_reasons"].values()) == 1
    assert_outputs_sane(out)


@pytest.mark.parametrize("where", [0.3, 0.5, 0.7, 0.9])
def test_random_bytes_in_raw_bag_warn(where, base, tmp_path, capsys):
    """4 KB of random bytes at a fraction of the bag: in image data the frame is skipped
    (counted, warned); in a record header the bag is read up to the damage, with a warning."""
    rec = copy(base, "bag", tmp_path)
    bag = rec / "recording.bag"
    data = bytearray(bag.read_bytes())
    at = int(len(data) * where)
    data[at:at + 4096] = np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    bag.write_bytes(bytes(data))
    out = tmp_path / "out"
    code, err = track(rec, out, capsys, quiet=False)
    assert "Traceback" not in err and "internal error" not in err
    if code == 0:
        doc = json.loads((out / "metrics.json").read_text())
        damaged = "bag index unusable" in err or doc["skipped_reasons"].get("corrupt_image", 0) >= 1
        assert damaged and "warning" in err, err
        if "bag index unusable" in err:     # the warning names the last frame read
            assert f"the last good frame is {doc['frames_total'] - 1})" in err, err
    else:
        assert code == 2 and "recording.bag" in error_line(err)
    assert_outputs_sane(out)


def test_reused_output_folder(base, tmp_path, capsys):
    out = tmp_path / "out"
    assert track(base / "folder", out, capsys)[0] == 0
    (out / "overlay.mp4").write_bytes(b"old video")
    code, err = track(base / "folder", out, capsys, "--max-frames", "4")
    assert code == 2 and re.search(r"out: holds another run's files .*--overwrite", error_line(err))
    assert len((out / "trajectory.csv").read_text().splitlines()) == 13   # untouched
    code, err = track(base / "folder", out, capsys, "--max-frames", "4", "--overwrite")
    assert code == 0, err
    assert not (out / "overlay.mp4").exists()
    assert len((out / "trajectory.csv").read_text().splitlines()) == 5
    (out / "notes.txt").write_text("mine")        # not a run's file: kept, and no refusal
    assert track(base / "folder", out, capsys, "--max-frames", "2", "--overwrite")[0] == 0
    assert (out / "notes.txt").read_text() == "mine"


def test_header_only_trajectory(tmp_path):
    from graphtrack.io.trajectory import COLUMNS, read_trajectory

    p = tmp_path / "trajectory.csv"
    p.write_text(",".join(COLUMNS) + "\n")
    t = read_trajectory(p)
    assert len(t["frame"]) == 0 and t["E"].shape == (0, 4, 4)


def track_with_file_limit(rec, out, limit: int, *extra) -> subprocess.CompletedProcess:
    """``graphtrack track rec --out out --quiet *extra`` in a process whose writes past
    ``limit`` bytes per file fail (RLIMIT_FSIZE: EFBIG, as a full disk fails them)."""
    args = ["track", str(rec), "--out", str(out), "--quiet", *extra]
    code = ("import resource, signal, sys\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))\n"
            "from graphtrack.cli import main\n"
            f"sys.exit(main({args!r}))\n")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)


@pytest.mark.slow
def test_full_disk_one_line_and_complete_lines(base, tmp_path):
    """RLIMIT_FSIZE makes every write past the limit fail (EFBIG), as a full disk does."""
    out = tmp_path / "out"
    p = track_with_file_limit(base / "folder", out, 1500)
    assert p.returncode == 2, p.stderr
    line = error_line(p.stderr)
    assert re.search(r"trajectory\.(csv|tum): cannot write", line), line
    for name in ("trajectory.csv", "trajectory.tum"):
        text = (out / name).read_text()
        assert text == "" or text.endswith("\n"), name
    assert_outputs_sane(out)
