"""graphtrack simulate: files, bag round trip, determinism, bad input."""
import csv

import numpy as np
import pytest

from graphtrack.cli import main
from graphtrack.sim import cached_recording, simulate
from graphtrack.sim.simulate import TRUTH_COLUMNS, Simulation

SIZE = (120, 160)


def test_bag_round_trip(tmp_path):
    from graphtrack.io.recording import open_recording

    out = simulate(tmp_path / "rec", "structured", frames=4, seed=7, size=SIZE, progress=False)
    for name in ("robot.json", "camera_calibration.yaml", "handeye.yaml", "recording.bag", "labels.csv",
                 "truth.csv"):
        assert (out / name).is_file(), name
    assert (out / "truth.csv").read_text().splitlines()[0] == TRUTH_COLUMNS
    sim = Simulation("structured", 4, seed=7, size=SIZE)
    rec = open_recording(out)
    frames = list(rec.frames())
    assert len(frames) == 4
    for i, f in enumerate(frames):
        img, _ = sim.render(i)
        assert np.array_equal(f.image, img)
        assert np.allclose(f.joints, sim.q_read[i, :6], atol=1e-12)
        assert f.jaw == pytest.approx(sim.q_read[i, 6], abs=1e-12)


def test_folder_form_and_same_seed_same_recording(tmp_path):
    a = simulate(tmp_path / "a", "tissue", frames=3, seed=11, size=SIZE, form="folder", progress=False)
    b = simulate(tmp_path / "b", "tissue", frames=3, seed=11, size=SIZE, form="folder", progress=False)
    c = simulate(tmp_path / "c", "tissue", frames=3, seed=12, size=SIZE, form="folder", progress=False)
    assert (a / "truth.csv").read_bytes() == (b / "truth.csv").read_bytes()
    assert (a / "truth.csv").read_bytes() != (c / "truth.csv").read_bytes()
    for i in range(3):
        name = f"frames/{i:06d}.png"
        assert (a / name).read_bytes() == (b / name).read_bytes()
    rows = list(csv.reader((a / "truth.csv").open()))
    assert len(rows) == 4 and rows[1][rows[0].index("ms")] == ""


def test_cached_recording(tmp_path, monkeypatch):
    monkeypatch.setenv("GRAPHTRACK_CACHE", str(tmp_path))
    p = cached_recording("structured", 2, 1, SIZE, progress=False)
    assert (p / ".complete").is_file() and p.parent == tmp_path / "sim"
    stamp = (p / "truth.csv").stat().st_mtime_ns
    assert cached_recording("structured", 2, 1, SIZE, progress=False) == p
    assert (p / "truth.csv").stat().st_mtime_ns == stamp


def test_a_recording_an_older_simulator_wrote_is_simulated_again(tmp_path):
    """simulated_once re-uses its recording while the simulator's CACHE_VERSION holds, and
    simulates it again when an older one wrote it (its truth.csv lacked the exact tip)."""
    from graphtrack.sim.simulate import CACHE_VERSION, simulated_once

    args = dict(scene="structured", frames=2, seed=4, size=SIZE, progress=False)
    p = simulated_once(tmp_path / "rec", **args)
    assert (p / ".complete").read_text() == f"v{CACHE_VERSION}\n"
    stamp = (p / "truth.csv").stat().st_mtime_ns
    assert simulated_once(tmp_path / "rec", **args) == p and (p / "truth.csv").stat().st_mtime_ns == stamp
    (p / ".complete").write_text("")                      # as the benchmarks' markers were
    (p / "truth.csv").write_text("frame,stamp\n")
    simulated_once(tmp_path / "rec", **args)
    assert "tip_x" in (p / "truth.csv").read_text().splitlines()[0]
    assert not list(tmp_path.glob("rec.tmp-*"))


@pytest.mark.parametrize("args", [
    ["--frames", "0"], ["--frames", "-3"], ["--frames", "100000000"], ["--scene", "moon"], ["--size", "32x960"],
    ["--size", "540x50"], ["--size", "big"], ["--form", "zip"], ["--form", "folder", "--compressed"],
])
def test_bad_input_exits_2(tmp_path, capsys, args):
    assert main(["simulate", str(tmp_path / "o"), "--frames", "2", "--size", "120x160"] + args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("graphtrack: error:")


def test_unwritable_out_exits_2(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["simulate", str(f / "sub"), "--frames", "2", "--size", "120x160"]) == 2
    assert "cannot write" in capsys.readouterr().err


def test_a_recording_that_was_not_simulated_is_never_replaced(tmp_path, capsys):
    """simulate into a lab's recording folder (a bag, robot.json, no truth.csv) deleted the
    bag with exit 0: refused unless --overwrite; a simulated one is replaced as before."""
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "patient7.bag").write_bytes(b"precious")
    (lab / "robot.json").write_text("{}")
    args = ["simulate", str(lab), "--frames", "2", "--size", "120x160", "--no-progress"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "lab: holds a recording that was not simulated (robot.json, patient7.bag)" in err and "--overwrite" in err
    assert (lab / "patient7.bag").read_bytes() == b"precious" and (lab / "robot.json").read_text() == "{}"
    assert main(args + ["--overwrite"]) == 0 and not (lab / "patient7.bag").exists()
    assert main(args + ["--seed", "1"]) == 0     # simulated before (truth.csv): replaced without asking


def test_truth_holds_the_exact_tip_in_the_camera_frame(tmp_path):
    """truth.csv's tip_x, tip_y, tip_z (left camera frame, m) project through K, D with
    OpenCV onto its tip_u, tip_v, and are robot.tool_tip through the TRUE hand-eye and joints."""
    import cv2

    from graphtrack.geometry.camera import load_calibration
    from graphtrack.robot.kinematics import link_transforms

    out = simulate(tmp_path / "rec", "structured", frames=5, seed=3, size=SIZE, form="folder", progress=False)
    rows = list(csv.DictReader((out / "truth.csv").open()))
    xyz = np.array([[float(r[k]) for k in ("tip_x", "tip_y", "tip_z")] for r in rows])
    uv = np.array([[float(r["tip_u"]), float(r["tip_v"])] for r in rows])
    cam = load_calibration(out / "camera_calibration.yaml").left
    proj = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0][:, 0]
    assert np.allclose(proj, uv, atol=1e-6)
    sim = Simulation("structured", 5, seed=3, size=SIZE)
    tip = sim.robot.tool_tip
    L = sim.E_he @ link_transforms(sim.robot, sim.q_true)[:, tip.link]
    assert np.allclose(xyz, L[:, :3, :3] @ np.asarray(tip.position) + L[:, :3, 3], atol=1e-12)


@pytest.mark.parametrize("noise_free", [True, False])
def test_3d_tip_error_is_against_the_exact_tip(tmp_path, noise_free):
    """tip_error_3d_mm of the kinematics (E = handeye.yaml) is |E tip(q~) - exact tip|, the
    joint readings' wrist noise included: 0 on a noise-free recording."""
    import json

    from graphtrack.io.handeye import load_handeye
    from graphtrack.robot.kinematics import link_transforms

    out = simulate(tmp_path / "rec", "tissue", frames=6, seed=5, size=SIZE, form="folder", progress=False,
                   noise_free=noise_free)
    assert main(["track", str(out), "--out", str(tmp_path / "o"), "--estimator", "kinematics", "--quiet"]) == 0
    got = np.array([float(r["tip_mm"]) for r in csv.DictReader((tmp_path / "o" / "truth_errors.csv").open())])
    sim = Simulation("tissue", 6, seed=5, size=SIZE, noise_free=noise_free)
    tip = sim.robot.tool_tip
    E = load_handeye(out / "handeye.yaml")
    L = E @ link_transforms(sim.robot, sim.q_read)[:, tip.link]
    placed = L[:, :3, :3] @ np.asarray(tip.position) + L[:, :3, 3]
    exact = np.array([[float(r[k]) for k in ("tip_x", "tip_y", "tip_z")]
                      for r in csv.DictReader((out / "truth.csv").open())])
    want = 1e3 * np.linalg.norm(placed - exact, axis=1)
    assert np.allclose(got, want, atol=1e-6)
    if noise_free:
        assert np.all(got < 1e-6)
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["tip_error_3d_mm"]["mean"] == pytest.approx(want.mean(), abs=1e-6)
