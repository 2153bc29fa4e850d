"""Videos at the recording's frame rate."""
import cv2
import numpy as np
import pytest

from graphtrack.io.video import StampedVideoWriter, frame_rate


@pytest.mark.parametrize("stamps,fps", [([0, 1 / 30, 2 / 30, 3 / 30], 30.0), ([10.0, 10.04, 10.08], 25.0),
                                        ([0, 0.1, 0.1, 0.2, 0.3], 10.0), ([np.nan, np.nan], 30.0), ([5.0], 30.0)])
def test_frame_rate(stamps, fps):
    assert frame_rate(stamps) == pytest.approx(fps)


@pytest.mark.parametrize("n", [3, 25])
def test_video_has_the_recording_rate_and_every_frame(tmp_path, n):
    path = tmp_path / "v.mp4"
    with StampedVideoWriter(path) as w:
        for i in range(n):
            w.write(np.full((48, 64, 3), 10 * i % 250, np.uint8), 100.0 + i / 30.0)
        assert w.frames_received == n
    cap = cv2.VideoCapture(str(path))
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(30.0, rel=1e-3)
    count = 0
    while cap.read()[0]:
        count += 1
    cap.release()
    assert count == n


def _fps_and_count(path):
    cap = cv2.VideoCapture(str(path))
    fps, n = cap.get(cv2.CAP_PROP_FPS), int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    return fps, n


def test_track_and_detect_videos_play_at_a_25_hz_recordings_rate(tmp_path, capsys):
    """A 25 Hz recording (stamps 40 ms apart) gives 25 frames/s videos, not the simulator's 30
    nor a fixed 15; ``track --video`` names overlay.mp4 when it is done."""
    import csv

    from graphtrack.cli import main
    from graphtrack.sim.simulate import simulate

    seq = simulate(tmp_path / "seq", "structured", frames=8, seed=2, size=(270, 480), progress=False,
                   form="folder")
    with open(seq / "joints.csv") as f:
        rows = list(csv.reader(f))
    for k, row in enumerate(rows[1:]):
        row[1] = repr(1000.0 + k / 25.0)
    with open(seq / "joints.csv", "w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(rows)

    out = tmp_path / "run"
    assert main(["track", str(seq), "--out", str(out), "--estimator", "kinematics", "--video"]) == 0
    done = capsys.readouterr().out.strip().splitlines()[-1]
    assert done.startswith(f"wrote {out}") and "overlay.mp4" in done and "metrics.json" in done
    fps, n = _fps_and_count(out / "overlay.mp4")
    assert fps == pytest.approx(25.0, rel=1e-3) and n == 8

    det = tmp_path / "det"
    assert main(["detect", str(seq), "--out", str(det), "--detector", "canny", "--video", "--quiet"]) == 0
    fps, n = _fps_and_count(det / "detections.mp4")
    assert fps == pytest.approx(25.0, rel=1e-3) and n == 8


def test_median_interval_of_stamps():
    """The one period estimate the readers share: positive steps only (a repeated stamp does
    not halve the period), integer nanoseconds differenced exactly, 0 without two stamps."""
    from graphtrack.io.stamps import median_interval

    assert median_interval([0.0, 0.1, 0.1, 0.2, 0.3]) == pytest.approx(0.1)
    t0 = 1_700_000_000_123_456_789
    assert median_interval([t0, t0 + 33_333_333, t0 + 66_666_667]) == 33_333_333.5
    assert median_interval([5.0]) == 0.0 and median_interval([2.0, 2.0]) == 0.0
