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
    assert len(rows) == 4 and rows[1][-1] == ""


def test_cached_recording(tmp_path, monkeypatch):
    monkeypatch.setenv("GRAPHTRACK_CACHE", str(tmp_path))
    p = cached_recording("structured", 2, 1, SIZE, progress=False)
    assert (p / ".complete").is_file() and p.parent == tmp_path / "sim"
    stamp = (p / "truth.csv").stat().st_mtime_ns
    assert cached_recording("structured", 2, 1, SIZE, progress=False) == p
    assert (p / "truth.csv").stat().st_mtime_ns == stamp


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
