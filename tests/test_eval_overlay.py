"""overlay.mp4: one video frame per tracked frame, drawn on the raw image."""
import numpy as np
import pytest

from graphtrack.eval.overlay import draw_overlay, video_frame_count

FRAMES = 12


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from graphtrack.sim.simulate import simulate

    return simulate(tmp_path_factory.mktemp("sim") / "rec", "tissue", frames=FRAMES, seed=5,
                    size=(270, 480), progress=False, form="folder")


def test_track_writes_overlay_with_one_frame_per_tracked_frame(rec, tmp_path):
    from graphtrack.track import TrackOptions, track

    res = track(rec, tmp_path / "out", TrackOptions(estimator="kinematics"), video=True, progress=False,
                max_frames=10, quiet=True)
    video = tmp_path / "out" / "overlay.mp4"
    assert video.stat().st_size > 0
    assert res["frames_tracked"] == 10
    assert video_frame_count(video) == 10
    import cv2

    cap = cv2.VideoCapture(str(video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) == 480 and int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == 270
    cap.release()


def test_a_run_stopped_early_keeps_the_frames_drawn_so_far(rec, tmp_path, monkeypatch):
    """Ctrl-C at frame 3, before the writer has the 10 frames it reads the frame rate from:
    overlay.mp4 holds the 3 frames trajectory.csv has rows for (the held frames were lost)."""
    import graphtrack.track as T

    real = T.tip_pixel

    def tip_then_stop(ctx, q, E, calls=[]):
        calls.append(1)
        if len(calls) > 3:
            raise KeyboardInterrupt
        return real(ctx, q, E)

    monkeypatch.setattr(T, "tip_pixel", tip_then_stop)
    with pytest.raises(KeyboardInterrupt):
        T.track(rec, tmp_path / "out", T.TrackOptions(estimator="kinematics"), video=True, progress=False, quiet=True)
    assert video_frame_count(tmp_path / "out" / "overlay.mp4") == 3
    assert len((tmp_path / "out" / "trajectory.csv").read_text().splitlines()) == 1 + 3


def test_refine_video_draws_the_refined_poses(rec, tmp_path, monkeypatch):
    """batch: the video's frames carry the poses trajectory.csv ends with (the refined ones),
    drawn in a second pass; the streamed video is what an interrupted run keeps."""
    from graphtrack.io.trajectory import read_trajectory
    from graphtrack.track import TrackOptions, overlay_run, track

    drawn: dict[str, list] = {}
    titles: dict[str, str | None] = {}

    class Recorder:   # OverlayWriter's interface; the file appears on close, as a video's would
        def __init__(self, path, ctx, labels=None, labels_right=None, title=None):
            self.path = path
            drawn[path.name] = []
            titles[path.name] = title

        def write(self, frame, estimate, detection=None, observation=None, tip=None, right=(None, None)):
            drawn[self.path.name].append((frame.index, np.array(estimate.E)))

        def close(self):
            self.path.write_bytes(b"video")

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.close()

    monkeypatch.setattr(overlay_run, "OverlayWriter", Recorder)
    out = tmp_path / "out"
    track(rec, out, TrackOptions(estimator="batch"), video=True, progress=False, max_frames=8, quiet=True)
    rows = read_trajectory(out / "trajectory.csv")
    streamed, refined = drawn["overlay.mp4"], drawn[overlay_run.REFINED_NAME]
    assert [i for i, _ in refined] == [i for i, _ in streamed] == rows["frame"].tolist()
    assert max(np.abs(E - F).max() for (_, E), F in zip(refined, rows["E"])) < 1e-9   # csv precision
    assert max(np.abs(E - F).max() for (_, E), F in zip(streamed, rows["E"])) > 1e-6   # the online ones
    assert (out / "overlay.mp4").read_bytes() == b"video" and not (out / overlay_run.REFINED_NAME).exists()
    assert titles == {"overlay.mp4": None, overlay_run.REFINED_NAME: "refined"}   # the video says which it shows


def test_draw_overlay_marks_tip_label_detection(rec):
    from graphtrack.detect.base import Detection, Observation
    from graphtrack.io.frame import Frame
    from graphtrack.io.context import TrackingContext
    from graphtrack.io.recording import open_recording
    from graphtrack.track import tip_pixel

    r = open_recording(rec)
    ctx = TrackingContext(r.robot, r.calibration.left, r.handeye)
    frame = next(f for f in r.frames() if isinstance(f, Frame))
    blank = np.zeros_like(frame.image)
    tip = tip_pixel(ctx, frame.q, ctx.handeye)
    det = Detection(shaft_lines=np.array([[100.0, 0.0]]), shaft_segments=np.array([[100.0, 20, 100, 200]]),
                    markers=np.array([[300.0, 150.0]]))
    obs = Observation("line-intensities", pixels=[np.array([[50.0, 60.0], [51.0, 60.0]])])
    img = draw_overlay(blank, ctx, frame.q, ctx.handeye, det, obs, tip, np.array([240.0, 135.0]))
    assert img.shape == blank.shape and not np.shares_memory(img, blank)
    u, v = np.round(tip).astype(int)
    assert tuple(img[v, u + 5]) == (0, 0, 255) and tuple(img[v - 5, u]) == (0, 0, 255)   # red ring, radius 5
    assert tuple(img[135, 240]) == (255, 255, 255)    # white label cross centre
    # an estimate on its label: both show, the cross inside the ring
    same = draw_overlay(blank, ctx, frame.q, ctx.handeye, tip_uv=np.array([240.0, 135.0]),
                        label_uv=np.array([240.0, 135.0]))
    assert tuple(same[135, 240]) == (255, 255, 255) and tuple(same[135, 245]) == (0, 0, 255)
    assert (img[..., 1] > 150).any()                  # green skeleton / yellow edges drawn
    mapped = ctx.camera.distort_pixels(np.array([100.0, 135.0]))
    x, y = np.round(mapped).astype(int)
    assert img[y, x - 1: x + 2].max() > 200           # the yellow edge, mapped to raw pixels
    for pixel in ([50.0, 60.0], [51.0, 60.0]):         # the pixel set: filled cyan dots in raw pixels
        x, y = np.round(ctx.camera.distort_pixels(np.array(pixel))).astype(int)
        assert tuple(img[y, x]) == (255, 255, 0) and tuple(img[y + 2, x]) == (255, 255, 0)


def test_drawing_the_video_is_not_the_tracking_cost(rec, tmp_path, monkeypatch):
    """A run with --video reports the drawing apart (timing_ms_median.video) and leaves it out
    of frame_ms_mean, so that compare's runtime table ranks the estimators, not which cell
    drew a video (the demo's did)."""
    import time

    from graphtrack.eval.overlay import OverlayWriter
    from graphtrack.track import TrackOptions, track

    slow = OverlayWriter.write
    monkeypatch.setattr(OverlayWriter, "write", lambda self, *a, **k: (time.sleep(0.05), slow(self, *a, **k))[1])
    m = track(rec, tmp_path / "out", TrackOptions(estimator="kinematics"), video=True, progress=False, quiet=True)
    assert m["timing_ms_median"]["video"] >= 50.0
    assert m["frame_ms_mean"] < 40.0 and m["timing_ms_median"]["write"] < 40.0
