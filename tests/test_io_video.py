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
