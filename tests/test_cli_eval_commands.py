"""demo, detect and refine end to end on tiny recordings."""
import csv
import json

import pytest

from graphtrack.cli import main


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from graphtrack.sim.simulate import simulate

    return simulate(tmp_path_factory.mktemp("sim") / "rec", "structured", frames=8, seed=7,
                    size=(270, 480), progress=False, form="folder")


@pytest.mark.slow
def test_demo_end_to_end(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("GRAPHTRACK_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--frames", "6", "--quiet"]) == 0
    text = capsys.readouterr().out
    for est in ("kinematics", "pf", "smoother"):
        assert est in text
    assert "video:" in text and "plot:" in text
    recs = sorted(p.name for p in (out / "runs").iterdir())
    assert recs == ["structured", "tissue"]
    tissue = next(r for r in recs if "tissue" in r)
    from graphtrack.eval.overlay import video_frame_count

    assert video_frame_count(out / "runs" / tissue / "smoother-line-intensities" / "overlay.mp4") == 6
    for r in recs:
        assert (out / "runs" / r / "pf-line-intensities" / "trajectory.tum").is_file()
        assert (out / f"accumulated_error_{r}.png").is_file()
    assert (out / "table.md").is_file()
    # the cache is reused and finished cells are not recomputed
    done = out / "runs" / tissue / "pf-line-intensities" / "done.json"
    before = done.stat().st_mtime_ns
    assert main(["demo", "--out", str(out), "--frames", "6", "--quiet"]) == 0
    assert done.stat().st_mtime_ns == before


def test_detect_writes_csv_and_video(rec, tmp_path):
    out = tmp_path / "det"
    assert main(["detect", str(rec), "--detector", "canny", "--out", str(out), "--max-frames", "5",
                 "--video", "--quiet"]) == 0
    with (out / "detections.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5 and [int(r["frame"]) for r in rows] == list(range(5))
    for k in ("rho_0", "theta_0", "x1_0", "Ee_0", "El_0", "n_markers", "ms"):
        assert k in rows[0]
    assert any(int(r["n_edges"]) > 0 for r in rows)
    from graphtrack.eval.overlay import video_frame_count

    assert video_frame_count(out / "detections.mp4") == 5


def test_detect_bad_recording_exit_2(tmp_path, capsys):
    assert main(["detect", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "graphtrack: error:" in capsys.readouterr().err


@pytest.mark.slow
def test_refine_is_track_with_batch(rec, tmp_path):
    from graphtrack.cli import build_parser

    args = build_parser().parse_args(["refine", str(rec), "--out", str(tmp_path / "r")])
    assert args.estimator == "batch"
    assert main(["refine", str(rec), "--out", str(tmp_path / "r"), "--max-frames", "6", "--quiet"]) == 0
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["estimator"] == "batch" and m["frames_tracked"] == 6
    rep = m["estimator_report"]           # the refinement's figures and the online smoother's counts
    assert rep["iterations"] >= 1 and rep["online"]["adopted"] >= 1
    assert (tmp_path / "r" / "trajectory.tum").is_file()


@pytest.mark.parametrize("command,estimator", [("track", "smoother"), ("refine", "batch")])
def test_no_edge_bias_reaches_the_estimator(rec, tmp_path, command, estimator):
    """--no-edge-bias turns the edge-bias state off in the smoother and the batch;
    by default it is on, for the pixel models and the polar models alike."""
    from graphtrack.cli import build_parser
    from graphtrack.commands.track import options_from_args
    from graphtrack.io.context import TrackingContext
    from graphtrack.estimate import make_estimator
    from graphtrack.io.recording import open_recording

    base = [command, str(rec), "--out", str(tmp_path / "o")] + (["--estimator", estimator] if command == "track" else [])
    r = open_recording(rec)
    ctx = TrackingContext(r.robot, r.calibration.left, r.handeye)
    for extra, observation, on in (([], "line-intensities", True), (["--no-edge-bias"], "line-intensities", False),
                                   ([], "line-intensities-polar", True),
                                   (["--no-edge-bias"], "line-intensities-polar", False)):
        opts = options_from_args(build_parser().parse_args(base + extra + ["--observation", observation]))
        est = make_estimator(estimator, ctx, **opts.estimation.keywords(estimator))
        assert est.bias is on, (extra, observation)


def test_detect_gate_is_trackings_start_up_gate(rec, tmp_path):
    """A nominal hand-eye some mm off puts the predicted shaft beyond the detector's own
    gate; detect gates as tracking does before its first estimate (MAX_GATE_PX) and finds
    the same edges it finds at the unshifted hand-eye."""
    import shutil

    import numpy as np
    import yaml

    from graphtrack.commands.detect import _predicted, start_gate
    from graphtrack.detect import make_detector
    from graphtrack.io.recording import open_recording
    from graphtrack.track import MAX_GATE_PX

    shifted = tmp_path / "shifted"
    shutil.copytree(rec, shifted)
    doc = yaml.safe_load((shifted / "handeye.yaml").read_text())
    doc["PSM1_tvec"][0] += 14.0   # mm: about 70 px at this size
    (shifted / "handeye.yaml").write_text(yaml.safe_dump(doc))

    own = make_detector("learned").association.max_offset
    assert start_gate(make_detector("learned")).max_offset == MAX_GATE_PX > own
    a, b = open_recording(rec), open_recording(shifted)
    frame = next(iter(a.frames()))
    rho_a = _predicted(a, frame.q, a.handeye, a.calibration.left.K)[:, 0]
    rho_b = _predicted(b, frame.q, b.handeye, b.calibration.left.K)[:, 0]
    assert own < np.max(np.abs(rho_a - rho_b)) < MAX_GATE_PX - 20   # beyond the detector's gate

    def edges(seq, out):
        assert main(["detect", str(seq), "--out", str(out), "--max-frames", "4", "--quiet"]) == 0
        with (out / "detections.csv").open() as f:
            rows = list(csv.DictReader(f))
        return np.array([[float(r[k]) for k in ("rho_0", "theta_0", "rho_1", "theta_1")] for r in rows])

    nominal, off = edges(rec, tmp_path / "a"), edges(shifted, tmp_path / "b")
    assert np.all(np.isfinite(off))
    np.testing.assert_allclose(off, nominal, atol=0.5)
