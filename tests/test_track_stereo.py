"""Stereo in the tracking loop: --mono reproduces the mono run exactly, a missing right
image falls back to a left-only update (counted), the triangulated-label 3-D error
against a hand-computed case, the side-by-side overlay, compare's mono / stereo axis."""
import csv
import json
from pathlib import Path

import numpy as np
import pytest

from graphtrack.detect.options import DetectionOptions
from graphtrack.eval.overlay import video_frame_count
from graphtrack.eval.stereo import disparity_depth_mm_per_px, stereo_tip_metrics, triangulate
from graphtrack.geometry.camera import Calibration, Camera
from graphtrack.sim import simulate
from graphtrack.study.cells import StudyOptions
from graphtrack.study.plan import plan
from graphtrack.track import TrackOptions, track

SIZE = (270, 480)
CANNY = DetectionOptions(detector="canny")


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    root = tmp_path_factory.mktemp("stereo")
    st = simulate(root / "stereo", frames=8, seed=700100, size=SIZE, form="folder", stereo=True, progress=False)
    mono = simulate(root / "mono", frames=8, seed=700100, size=SIZE, form="folder", progress=False)
    return Path(st), Path(mono)


def _poses(out: Path) -> list[list[str]]:
    with (out / "trajectory.csv").open() as f:
        rows = list(csv.DictReader(f))
    return [[r[k] for k in ("frame", "tx", "ty", "tz", "qx", "qy", "qz", "qw")] for r in rows]


def test_mono_flag_reproduces_the_mono_trajectory(recordings, tmp_path):
    st, mono = recordings
    a = track(st, tmp_path / "a", TrackOptions(detection=CANNY, stereo=False), progress=False, quiet=True)
    b = track(mono, tmp_path / "b", TrackOptions(detection=CANNY), progress=False, quiet=True)
    assert _poses(tmp_path / "a") == _poses(tmp_path / "b")
    assert a["stereo"] is False and "stereo" not in b


def test_stereo_run_and_its_metrics(recordings, tmp_path):
    st, _ = recordings
    m = track(st, tmp_path / "s", TrackOptions(detection=CANNY), progress=False, quiet=True, video=True)
    assert m["stereo"] is True and m["frames_left_only"] == 0
    assert m["frames_scored_3d_labels"] == 8 and m["frames_scored_right"] == 8
    assert np.isfinite(m["tip_error_3d_labels_mm"]["mean"]) and np.isfinite(m["tip_error_right_px"]["mean"])
    doc = json.loads((tmp_path / "s" / "metrics.json").read_text())
    assert doc["tip_error_3d_labels_mm"] == m["tip_error_3d_labels_mm"]
    # the smoother's policy counts: the start-up search ran and its mode was adopted; no more
    # outlier frames than trajectory.csv flags
    rep = doc["estimator_report"]
    assert rep["searches"] >= rep["adopted"] >= 1
    traj = np.atleast_1d(np.genfromtxt(tmp_path / "s" / "trajectory.csv", delimiter=",", names=True))
    assert rep["outlier_frames"] <= traj["outlier"].sum()
    import cv2
    cap = cv2.VideoCapture(str(tmp_path / "s" / "overlay.mp4"))
    ok, img = cap.read()
    cap.release()
    assert ok and img.shape[:2] == (SIZE[0], 2 * SIZE[1])          # left | right
    assert video_frame_count(tmp_path / "s" / "overlay.mp4") == 8


def test_kinematics_video_draws_the_right_image(recordings, tmp_path):
    """README's calibration check (`--estimator kinematics --video`): the kinematics uses no
    image, but its stereo video reads the right images to draw the right panel (it was
    black); the run still reports stereo: false."""
    import cv2

    st, _ = recordings
    m = track(st, tmp_path / "k", TrackOptions(estimator="kinematics"), progress=False, quiet=True, video=True)
    assert m["stereo"] is False
    cap = cv2.VideoCapture(str(tmp_path / "k" / "overlay.mp4"))
    ok, img = cap.read()
    cap.release()
    right = cv2.imread(str(sorted((st / "frames_right").iterdir())[0]))
    panel = img[40:, SIZE[1]:].astype(float)                           # below the caption
    assert ok and np.abs(panel - right[40:]).mean() < 8.0             # the right image, not black


def test_detect_names_every_file_it_wrote(recordings, tmp_path, capsys):
    from graphtrack.cli import main

    st, _ = recordings
    assert main(["detect", str(st), "--out", str(tmp_path / "d"), "--detector", "canny", "--max-frames", "2"]) == 0
    assert capsys.readouterr().out.strip().endswith(f"wrote {tmp_path / 'd'}/detections.csv, detections_right.csv")
    assert (tmp_path / "d" / "detections_right.csv").is_file()


def test_missing_right_image_falls_back_to_left_only(recordings, tmp_path):
    import shutil

    st, _ = recordings
    seq = tmp_path / "seq"
    shutil.copytree(st, seq)
    right = sorted((seq / "frames_right").iterdir())
    right[3].unlink()
    m = track(seq, tmp_path / "o", TrackOptions(detection=CANNY), progress=False, quiet=True)
    assert m["frames_tracked"] == 8 and m["frames_skipped"] == 0
    assert m["frames_left_only"] == 1
    assert sum(m["right_skipped_reasons"].values()) == 1
    # a --mono run does not read the right images, so the missing one is not counted
    m = track(seq, tmp_path / "m", TrackOptions(detection=CANNY, stereo=False), progress=False, quiet=True)
    assert m["stereo"] is False and m["frames_left_only"] == 0
    assert sum(m["right_skipped_reasons"].values()) == 0


def test_triangulated_labels_hand_computed():
    """Rectified rig (no distortion, R = I, T = (-5 mm, 0, 0)): a point at (10, 20, 100) mm
    projects to u_L = f X/Z + cx, u_R = f (X - 5 mm)/Z + cx, same v; triangulation gives
    it back; an estimate 1 mm deeper scores 1 mm in 3-D and, in the right image, its
    projection's distance to u_R."""
    K = np.array([[1000.0, 0, 479.5], [0, 1000.0, 269.5], [0, 0, 1]])
    cal = Calibration(Camera(K, np.zeros(5), 540, 960), Camera(K.copy(), np.zeros(5), 540, 960),
                      np.eye(3), np.array([-0.005, 0.0, 0.0]))
    X = np.array([0.010, 0.020, 0.100])
    uL = np.array([1000 * 0.010 / 0.1 + 479.5, 1000 * 0.020 / 0.1 + 269.5])     # (579.5, 469.5)
    uR = np.array([1000 * 0.005 / 0.1 + 479.5, 1000 * 0.020 / 0.1 + 269.5])     # (529.5, 469.5)
    np.testing.assert_allclose(triangulate(cal, uL[None], uR[None])[0], X, atol=1e-9)
    est = np.array([[0.010, 0.020, 0.101]])
    doc = stereo_tip_metrics(cal, [7], est, {7: uL}, {7: uR})
    assert doc["frames_scored_3d_labels"] == 1
    assert doc["tip_error_3d_labels_mm"]["mean"] == pytest.approx(1.0, abs=1e-6)
    # right image: the estimate projects to (1000 * 0.005 / 0.101 + 479.5, 1000 * 0.02 / 0.101 + 269.5)
    expect = np.hypot(1000 * 0.005 / 0.101 - 50.0, 1000 * 0.020 / 0.101 - 200.0)
    assert doc["tip_error_right_px"]["mean"] == pytest.approx(expect, rel=1e-9)
    assert stereo_tip_metrics(Calibration(cal.left), [7], est, {7: uL}, {7: uR}) == {}


def test_labels_depth_per_pixel_of_disparity_matches_triangulation():
    """labels_3d_mm_per_px against cv2's triangulation on the rectified rig above: moving the
    right label 0.1 px (disparity) moves the triangulated point along z by 0.1 * z^2 / (f b);
    at z = 100 mm, f = 1000 px, b = 5 mm that is 2 mm per px."""
    K = np.array([[1000.0, 0, 479.5], [0, 1000.0, 269.5], [0, 0, 1]])
    cal = Calibration(Camera(K, np.zeros(5), 540, 960), Camera(K.copy(), np.zeros(5), 540, 960),
                      np.eye(3), np.array([-0.005, 0.0, 0.0]))
    uL, uR = np.array([[479.5, 269.5]]), np.array([[429.5, 269.5]])            # the point (0, 0, 100) mm
    dz = 1e3 * (triangulate(cal, uL, uR - [0.1, 0.0])[0, 2] - triangulate(cal, uL, uR + [0.1, 0.0])[0, 2]) / 0.2
    assert disparity_depth_mm_per_px(cal, 0.1) == pytest.approx(2.0)
    assert disparity_depth_mm_per_px(cal, 0.1) == pytest.approx(abs(dz), rel=1e-3)
    doc = stereo_tip_metrics(cal, [7], np.array([[0.0, 0.0, 0.1]]), {7: uL[0]}, {7: uR[0]})
    assert doc["labels_3d_mm_per_px"] == pytest.approx(2.0)


def test_track_prints_the_stereo_and_truth_figures():
    from graphtrack.commands.track import scored_lines

    doc = {"tip_error_right_px": {"mean": 1.5}, "frames_scored_right": 40,
           "tip_error_3d_labels_mm": {"mean": 12.0}, "labels_3d_mm_per_px": 9.4,
           "tip_error_3d_mm": {"mean": 0.25}, "tip_error_3d_depth_mm": {"mean": 0.13},
           "tip_error_3d_lateral_mm": {"mean": 0.2}}
    lines = scored_lines(doc)
    assert len(lines) == 3 and "1.50 px" in lines[0] and "9.4 mm of depth" in lines[1]
    assert "0.250 mm mean (0.130 along the viewing ray, 0.200 across it)" in lines[2]
    assert scored_lines({"tip_error_3d_mm": {"mean": float("nan")}}) == []      # nothing scored: no line


def test_compare_plans_a_mono_stereo_axis(tmp_path):
    both = StudyOptions(estimators=["kinematics", "smoother"], observations=["line-intensities"], views="both")
    cells, _ = plan([str(tmp_path)], both, tmp_path / "study", names=["r"])
    assert [c.key for c in cells] == ["kinematics", "smoother-line-intensities", "smoother-line-intensities-mono"]
    assert [c.track_options().stereo for c in cells[1:]] == [True, False]
    assert cells[2].row == ("line-intensities", "smoother (mono)")
    mono = StudyOptions(estimators=["smoother"], observations=["line-intensities"], views="mono")
    (cell,), _ = plan([str(tmp_path)], mono, tmp_path / "study2", names=["r"])
    assert cell.key == "smoother-line-intensities" and cell.track_options().stereo is False


def test_swapped_left_and_right_images_are_refused(recordings, tmp_path):
    """frames/ and frames_right/ exchanged: the smoother starts over on every other frame
    (no pose explains both images), so the run exits 2 naming the left/right order; the
    same images with --mono track with one start."""
    import shutil

    from graphtrack.errors import InputError

    st, _ = recordings
    sw = tmp_path / "swapped"
    shutil.copytree(st, sw)
    (sw / "frames").rename(sw / "left")
    (sw / "frames_right").rename(sw / "frames")
    (sw / "left").rename(sw / "frames_right")
    with pytest.raises(InputError, match="which images are the left ones"):
        track(sw, tmp_path / "s", TrackOptions(detection=CANNY), progress=False, quiet=True)
    doc = json.loads((tmp_path / "s" / "metrics.json").read_text())   # written before the verdict
    assert doc["estimator_report"]["adopted"] >= 4 and doc["frames_with_detections"] == 8
    m = track(sw, tmp_path / "m", TrackOptions(detection=CANNY, stereo=False), progress=False, quiet=True)
    assert m["estimator_report"]["adopted"] == 1 and m["recording_warnings"] == []
    ok = track(st, tmp_path / "ok", TrackOptions(detection=CANNY), progress=False, quiet=True)
    assert ok["estimator_report"]["adopted"] == 1 and ok["recording_warnings"] == []


def test_kinematics_on_a_stereo_recording_uses_neither_image(recordings, tmp_path):
    st, _ = recordings
    m = track(st, tmp_path / "k", TrackOptions(estimator="kinematics"), progress=False, quiet=True)
    assert m["stereo"] is False and m["frames_left_only"] == 0
    assert sum(m["right_skipped_reasons"].values()) == 0        # the right images were not read
