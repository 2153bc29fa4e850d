"""The Python API as the README shows it: Pipeline.step on a recording's frames (stereo
too) equals `track`, frames a caller builds are checked as a recording's are, an
offline estimator's refinement comes from Pipeline.finish, and `track` raises
InputError where the command line exits 2."""
import csv
import dataclasses

import numpy as np
import pytest

from graphtrack.detect.options import DetectionOptions
from graphtrack.errors import FrameError, InputError
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.geometry.se3 import matrix_to_quaternion
from graphtrack.io.context import TrackingContext
from graphtrack.io.recording import open_recording
from graphtrack.sim import simulate
from graphtrack.track import Pipeline, TrackOptions, track

CANNY = DetectionOptions(detector="canny")


@pytest.fixture(scope="module")
def stereo(tmp_path_factory):
    return simulate(tmp_path_factory.mktemp("api") / "rec", frames=6, seed=700100, size=(270, 480), form="folder",
                    stereo=True, progress=False)


def _rows(out):
    with (out / "trajectory.csv").open() as f:
        return np.array([[float(r[k]) for k in ("tx", "ty", "tz", "qx", "qy", "qz", "qw")] for r in csv.DictReader(f)])


def _pose(Es):
    """(tx, ty, tz, qx, qy, qz, qw) per pose, as trajectory.csv holds them (exact: repr)."""
    return np.array([np.concatenate([E[:3, 3], matrix_to_quaternion(E[:3, :3])]) for E in Es])


def _stepped(rec, options, ctx=None):
    pipe = Pipeline(ctx or TrackingContext.of(rec, options.stereo), options)
    poses = []
    for frame in rec.frames():
        assert not isinstance(frame, FrameError)
        poses.append(pipe.step(frame)[0].E)
    return pipe, poses


@pytest.mark.parametrize("stereo_run", [True, False])
def test_the_readme_loop_equals_track_mono_and_stereo(stereo, tmp_path, stereo_run):
    options = TrackOptions(estimator="pf", detection=CANNY, stereo=stereo_run,
                           estimation=EstimatorOptions(particles=200))
    rec = open_recording(stereo)
    pipe, poses = _stepped(rec, options)
    assert pipe.stereo == stereo_run
    track(stereo, tmp_path / "cli", options, progress=False, quiet=True)
    np.testing.assert_array_equal(_pose(poses), _rows(tmp_path / "cli"))


def test_mono_options_on_a_stereo_context_use_the_left_image_only(stereo):
    rec = open_recording(stereo)
    options = TrackOptions(estimator="pf", detection=CANNY, stereo=False, estimation=EstimatorOptions(particles=200))
    pipe, mono = _stepped(rec, options, TrackingContext.of(rec))      # a stereo context, --mono options
    assert not pipe.stereo and not pipe.ctx.stereo
    _, left_only = _stepped(rec, options, TrackingContext.of(rec, stereo=False))
    np.testing.assert_array_equal(np.array(mono), np.array(left_only))


def test_a_frame_built_by_the_caller_is_checked_as_a_recordings_are(stereo):
    rec = open_recording(stereo)
    frames = list(rec.frames())
    pipe = Pipeline(TrackingContext.of(rec), TrackOptions(estimator="kinematics"))
    f0 = frames[0]
    bad = {
        "nan_joints": dataclasses.replace(f0, joints=np.where(np.arange(6) == 2, np.nan, f0.joints)),
        "joint_count": dataclasses.replace(f0, joints=f0.joints[:5]),
        "joint_range": dataclasses.replace(f0, joints=np.degrees(f0.joints) + 400.0),
        "image_size": dataclasses.replace(f0, image=f0.image[::2, ::2]),
        # a caller's 16-bit, float, grey or BGRA array: refused, not tracked on an empty detection
        "image_format": dataclasses.replace(f0, image=f0.image.astype(np.uint16) * 257),
    }
    for image in (f0.image / 255.0, f0.image[:, :, 0], np.dstack([f0.image, f0.image[:, :, :1]])):
        with pytest.raises(FrameError, match="8-bit BGR"):
            pipe.step(dataclasses.replace(f0, image=image))
    for jaw in (None, "0.4"):
        with pytest.raises(FrameError, match="not numbers"):
            pipe.step(dataclasses.replace(f0, jaw=jaw))
    for stamp in ("1.0", True):
        with pytest.raises(FrameError, match="not a finite number"):
            pipe.step(dataclasses.replace(f0, stamp=stamp))
    with pytest.raises(FrameError, match=r"shape \(1, 6\): one reading is a flat vector"):
        pipe.step(dataclasses.replace(f0, joints=f0.joints[None]))
    with pytest.raises(FrameError, match="the jaw goes in Frame.jaw"):
        pipe.step(dataclasses.replace(f0, joints=f0.q))
    with pytest.raises(FrameError, match="no jaw reading"):
        pipe.step(dataclasses.replace(f0, jaw=float("nan")))
    for reason, frame in bad.items():
        with pytest.raises(FrameError) as e:
            pipe.step(frame)
        assert e.value.reason == reason and str(e.value).startswith("frame 0: ")
    pipe.step(frames[1])
    with pytest.raises(FrameError) as e:                  # not after the last stepped frame
        pipe.step(frames[0])
    assert e.value.reason == "stamp_order"
    # a right image of another size is not used: a left-only update, counted
    stereo_pipe = Pipeline(TrackingContext.of(rec), TrackOptions(estimator="pf", detection=CANNY))
    stereo_pipe.step(dataclasses.replace(f0, image_right=f0.image_right[::2, ::2]))
    stereo_pipe.step(dataclasses.replace(frames[1], image_right=frames[1].image_right.astype(np.float32)))
    stereo_pipe.step(dataclasses.replace(frames[2], image_right=frames[2].image.copy()))
    assert stereo_pipe.left_only == 3
    assert stereo_pipe.right_refused == {"image_size": 1, "image_format": 1, "same_as_left": 1}


def test_tip_pixel_names_a_wrong_joint_vector_or_pose(stereo):
    """tip_pixel takes Frame.q (the DH joints, then the jaw) and a 4x4 E; it agrees with
    OpenCV's projection of the tip placed by forward kinematics."""
    import cv2

    from graphtrack.robot.kinematics import link_transforms
    from graphtrack.track import tip_pixel

    rec = open_recording(stereo)
    ctx = TrackingContext.of(rec)
    f0 = next(iter(rec.frames()))
    E = ctx.handeye
    tip = ctx.robot.tool_tip
    L = E @ link_transforms(ctx.robot, f0.q)[tip.link]
    p = L[:3, :3] @ np.asarray(tip.position) + L[:3, 3]
    want = cv2.projectPoints(p[None], np.zeros(3), np.zeros(3), ctx.camera.K, ctx.camera.dist)[0][0, 0]
    np.testing.assert_allclose(tip_pixel(ctx, f0.q, E), want, atol=1e-6)
    with pytest.raises(ValueError, match=r"expected \(7,\): 6 DH joints then the jaw"):
        tip_pixel(ctx, f0.joints, E)                       # the jaw left out
    with pytest.raises(ValueError, match=r"expected \(7,\)"):
        tip_pixel(ctx, np.concatenate([f0.q, [0.0]]), E)
    with pytest.raises(ValueError, match="4x4"):
        tip_pixel(ctx, f0.q, E[:3])


def test_finish_returns_the_batch_refinement_track_writes(stereo, tmp_path):
    options = TrackOptions(estimator="batch", detection=CANNY)
    rec = open_recording(stereo)
    pipe, _ = _stepped(rec, options)
    refined = pipe.finish()
    track(stereo, tmp_path / "b", options, progress=False, quiet=True)
    np.testing.assert_array_equal(_pose([e.E for e in refined]), _rows(tmp_path / "b"))
    assert Pipeline(TrackingContext.of(rec), TrackOptions(estimator="pf")).finish() is None


@pytest.mark.parametrize("options, match", [
    (TrackOptions(observation="bar"), r"observation 'bar': choose from canny, "),
    (TrackOptions(estimator="ekf"), r"estimator 'ekf': choose from kinematics, pf, smoother, batch"),
    (TrackOptions(estimation=EstimatorOptions(lag=-1)), r"--lag must be a positive finite number"),
    (TrackOptions(estimation=EstimatorOptions(lag=float("nan"))), r"--lag must be a positive finite number"),
    (TrackOptions(estimation=EstimatorOptions(lag=float("inf"))), r"--lag must be a positive finite number"),
    (TrackOptions(estimation=EstimatorOptions(particles=2.5)), r"--particles must be a whole number"),
    (TrackOptions(estimation=EstimatorOptions(particles=True)), r"--particles must be a whole number"),
    (TrackOptions(stereo="no"), r"stereo must be True or False"),
    (TrackOptions(seed=-1), r"--seed must be an integer"),
])
def test_track_checks_its_options_before_writing(stereo, tmp_path, options, match):
    with pytest.raises(InputError, match=match):
        track(stereo, tmp_path / "o", options, progress=False, quiet=True)
    assert not (tmp_path / "o").exists()


def test_track_raises_where_the_command_line_exits_2(stereo, tmp_path):
    options = TrackOptions(estimator="kinematics")
    with pytest.raises(InputError, match=r"is the recording folder itself"):
        track(stereo, stereo, options, progress=False, quiet=True)
    track(stereo, tmp_path / "o", options, progress=False, quiet=True)
    with pytest.raises(InputError, match=r"holds another run's files"):
        track(stereo, tmp_path / "o", options, progress=False, quiet=True)
    track(stereo, tmp_path / "o", options, progress=False, quiet=True, overwrite=True)
    with pytest.raises(InputError, match=r"empty path, which would mean the current folder"):
        track(stereo, "", options, progress=False, quiet=True)
    for n in (0, 2.5, True):
        with pytest.raises(InputError, match=r"--max-frames must be a whole number of at least 1"):
            track(stereo, tmp_path / "m", options, progress=False, quiet=True, max_frames=n)
    from graphtrack.commands.detect import detect_recording
    with pytest.raises(InputError, match=r"empty path, which would mean the current folder"):
        detect_recording(stereo, "", quiet=True)
    with pytest.raises(InputError, match=r"--max-frames must be a whole number of at least 1"):
        detect_recording(stereo, tmp_path / "d", max_frames=0, quiet=True)
    with pytest.raises(InputError, match=r"a folder; give the file"):
        from graphtrack.io.trajectory import read_trajectory
        read_trajectory(tmp_path / "o")


def test_limit_threads_refuses_a_count_below_one_before_changing_anything():
    import os

    from graphtrack.threads import limit_threads

    before = os.environ.get("OMP_NUM_THREADS")
    for n in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="at least 1"):
            limit_threads(n)
    assert os.environ.get("OMP_NUM_THREADS") == before


def test_a_one_frame_run_has_no_steady_rate():
    """frame_ms_mean / fps_steady cover frames 1 ...: none in a one-frame run (null), not
    frame 0's start-up cost."""
    import math

    from graphtrack.track.runlog import RunLog

    run = RunLog()
    run.frame_ms = [504.0]
    s = run.summary(0.6)
    assert math.isnan(s["frame_ms_mean"]) and math.isnan(s["fps_steady"])
    run.frame_ms = [504.0, 20.0, 30.0]
    s = run.summary(0.6)
    assert s["frame_ms_mean"] == 25.0 and s["fps_steady"] == 40.0


def test_a_video_that_ended_warns_once(capsys):
    """video_ended: the first message names every frame left without an image, so the
    rest are counted without a line each."""
    from graphtrack.track.runlog import SkipCounter

    skipped = SkipCounter()
    for k in range(15, 40):
        skipped.skip(FrameError(k, "video_ended", f"video.mp4 ended before frame {k}"), quiet=False)
    lines = capsys.readouterr().err.splitlines()
    assert skipped["video_ended"] == 25 and len(lines) == 1 and "frame 15" in lines[0]


def test_many_skips_of_one_reason_are_counted_not_each_listed(capsys):
    """A joints.csv with 40 rows past the last image warned 40 times; each reason now warns
    its first WARN_EACH frames, then once that the rest are counted."""
    from graphtrack.track.runlog import SkipCounter

    skipped = SkipCounter()
    for k in range(25):
        skipped.skip(FrameError(k, "missing_image", "frames/ has no image"), quiet=False)
    skipped.skip(FrameError(30, "corrupt_image", "does not decode"), quiet=False)
    lines = capsys.readouterr().err.splitlines()
    assert skipped["missing_image"] == 25 and skipped["corrupt_image"] == 1
    assert len(lines) == SkipCounter.WARN_EACH + 2
    assert "skipping frame 10 and further 'missing_image' frames: counted in metrics.json" in lines[-2]
    assert lines[-1].startswith("graphtrack: warning: skipping frame 30")
