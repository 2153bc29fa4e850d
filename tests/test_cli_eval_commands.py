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
