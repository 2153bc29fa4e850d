"""The tracking loop: recording -> undistort -> detect -> observe -> estimate -> write.

``track`` streams a recording frame by frame through one estimator and writes
trajectory.csv / trajectory.tum row by row (flushed, so an interruption loses
nothing already computed), then metrics.json. A bad frame (corrupt image, NaN
joints, ...) is skipped, warned about and counted in metrics.json; bad options,
output folders and recordings raise InputError before anything is written, and a
run that tracked nothing raises it after metrics.json (what the command line
reports with exit status 2).

The per-frame pipeline is :mod:`graphtrack.track.pipeline` (re-exported here:
TrackOptions, Pipeline, tip_pixel, ...); what a run collects as it goes,
:mod:`graphtrack.track.runlog`.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from graphtrack.allocator import keep_freed_memory
from graphtrack.errors import FrameError, InputError
from graphtrack.estimate import estimator_class, require_shaft
from graphtrack.estimate.base import STD_COLUMNS, Estimate
from graphtrack.estimate.prior_region import PRIOR_HINT, correction
from graphtrack.eval.metrics import check_truth, evaluate_against_truth, tip_metrics
from graphtrack.eval.robustness import no_detection_stretches
from graphtrack.eval.stereo import stereo_tip_metrics
from graphtrack.io.context import TrackingContext
from graphtrack.io.run_output import (check_run_arguments, deferred_interrupts, lock_problem, lock_refused,
                                      outside_recording, prepare_run_dir, require_lock, require_tool_in_front,
                                      require_tracked, unexplained_problem, write_json)
from graphtrack.io.outdir import writable_dir
from graphtrack.io.recording import Recording, open_recording
from graphtrack.io.topics import TopicSelection
from graphtrack.io.trajectory import TrajectoryWriter
from graphtrack.track.pipeline import MAX_GATE_PX, Pipeline, TrackOptions, tip_pixel, tip_point  # noqa: F401
from graphtrack.track.overlay_run import RunOverlay
from graphtrack.track.runlog import RunLog, read_frames, warn


def _evaluated_tip(rec: Recording, tip_feature: str | None):
    """The robot with the point that is evaluated as the tool tip (format doc: robot.json's
    ``tool_tip``; when it is missing, evaluation must be told which point feature to use)."""
    robot = rec.robot
    if tip_feature is not None:
        names = {p.name: p for p in robot.point_features}
        if tip_feature not in names:
            raise InputError(f"--tip-feature: {rec.path / 'robot.json'} has no point feature {tip_feature!r} "
                             f"(it has: {', '.join(names) or 'none'})")
        return dataclasses.replace(robot, tool_tip=names[tip_feature])
    if robot.tool_tip is None and rec.labels:
        raise InputError(f"{rec.path / 'robot.json'}: no tool_tip, so labels.csv cannot be scored; "
                         "name the point feature to evaluate with --tip-feature NAME")
    return robot


def _jaw_in_joints(rec: Recording) -> str:
    """For a bag without jaw messages whose joint messages hold one value more than the DH
    joints: the note that graphtrack reads the jaw from its own topic only."""
    lengths = rec.source.joint_tables()[0].lengths
    n = rec.n_joints
    if n is None or not len(lengths) or not np.all(lengths == n + 1):
        return ""
    return (f" (its joint messages on {rec.source.joint_topic} hold {n + 1} values for robot.json's {n} DH "
            "joints: a jaw recorded as the joint message's last value is not read; graphtrack reads the "
            "jaw from a topic of its own, one value per message)")


def _grey_markers(frame, ctx: TrackingContext, options: TrackOptions, robot_json: Path) -> str | None:
    """For greyscale frames when markers are to be found (by colour): the warning line, or
    InputError when the robot has no shaft either (nothing could be tracked). "" when the
    frames are in colour or markers are not used, None while undecided (a flat frame: the
    light off, a fade-in)."""
    img = frame.image
    if not (ctx.robot.point_features and options.detection.markers and img is not None):
        return ""
    if int(img.max()) - int(img.min()) < FLAT_LEVELS:
        return None
    if not (img.ndim == 2 or img.shape[2] == 1 or (np.array_equal(img[..., 0], img[..., 1])
                                                  and np.array_equal(img[..., 1], img[..., 2]))):
        return ""
    if not ctx.robot.shaft_features:
        raise InputError(f"{robot_json}: no shaft_features, and the frames are greyscale (frame {frame.index}) "
                         "while painted markers are found by their colour: nothing in the images can be tracked")
    return ("the frames are greyscale: painted markers are found by their colour, so none will be, and the "
            "shaft alone is tracked (--no-markers says so without this warning)")


#: grey levels a frame must span to be judged colour or greyscale (a darker one is the light off)
FLAT_LEVELS = 16


def _observable(rec: Recording, ctx: TrackingContext, options: TrackOptions) -> list[str]:
    """What an estimator that reads images can observe of the robot: InputError when
    nothing (no shaft_features, and no point_features or --no-markers: the output would
    be the prior); the warning line when only the markers."""
    if ctx.robot.shaft_features:
        return []
    robot_json = rec.path / "robot.json"
    require_shaft(options.estimator, ctx.robot, robot_json)   # the estimator's own refusal, with the path
    if not ctx.robot.point_features or not options.detection.markers:
        why = "no point_features" if not ctx.robot.point_features else "its markers are off (--no-markers)"
        raise InputError(f"{robot_json}: no shaft_features and {why}: {options.estimator} has nothing in the "
                         "images to track (its output would be handeye.yaml's kinematics); describe the shaft "
                         "(shaft_features) or painted markers, or run --estimator kinematics")
    return [f"{robot_json} has no shaft_features: tracking from the markers alone, without the global "
            "start-up search"]


def _open(path: str | Path, options: TrackOptions, quiet: bool,
          topics: TopicSelection) -> tuple[Recording, TrackingContext]:
    """The recording (checked; its warnings printed unless quiet) and its tracking context."""
    rec = open_recording(path, topics=topics)
    if rec.robot.has_gripper and not rec.has_jaw:
        where = (f"no messages on {rec.source.jaw_topic}; name the jaw topic with --jaw-topic"
                 f"{_jaw_in_joints(rec)}"
                 if isinstance(getattr(rec.source, "jaw_topic", None), str)
                 else "joints.csv's 'jaw' column holds no finite value")
        raise InputError(f"{rec.path}: robot.json says has_gripper but the recording has no jaw readings "
                         f"({where}); the tool tip would be wrong without them")
    for w in rec.warnings:
        warn(f"warning: {w}", quiet)
    rec.robot = _evaluated_tip(rec, options.tip_feature)
    return rec, TrackingContext.of(rec, options.stereo)



def _refine(pipe: Pipeline, run: RunLog, writer: TrajectoryWriter, extra: list[str]) -> None:
    """An offline estimator's refined estimates replace every streamed row and tip."""
    refined = pipe.finish()
    if refined is None:
        return
    run.tips, rows = [], []
    for i, ((fi, stamp, q, ms, E0), est) in enumerate(zip(run.rows, refined)):
        E = est.E if np.all(np.isfinite(est.E)) else E0   # a non-finite refinement keeps the streamed pose
        tip = tip_pixel(pipe.ctx, q, E)
        run.tips.append(tip)
        run.rows[i] = (fi, stamp, q, ms, E)
        rows.append((fi, stamp, E, tip, ms, _extras(est, extra)))
    writer.rewrite_all(rows)


def track(path: str | Path, out: str | Path, options: TrackOptions, video: bool = False,
          progress: bool = True, max_frames: int | None = None, quiet: bool = False,
          topics: TopicSelection = TopicSelection(), overwrite: bool = False) -> dict:
    """Run one estimator over a recording; write the outputs into ``out``; return
    metrics.json's content.

    ``topics``: the arm and bag topics to read (default: detected, :mod:`graphtrack.io.topics`);
    ``overwrite``: replace another run's files in ``out`` (refused otherwise).

    Raises InputError where the command line exits 2: bad options (:meth:`TrackOptions.check`),
    an ``out`` that is (inside) the recording or holds another run's files, an unreadable
    recording; after metrics.json, a run that tracked nothing or never had the tool in view
    (:mod:`graphtrack.io.run_output`). Freed frame buffers are kept (:mod:`graphtrack.allocator`).
    """
    options.check()
    check_run_arguments(out, max_frames)
    outside_recording(out, path)
    prepare_run_dir(out, overwrite)
    keep_freed_memory()
    rec, ctx = _open(path, options, quiet, topics)
    check_truth(path)   # for evaluation only (never given to the estimator): refused before the run
    out = writable_dir(out)
    notes = _observable(rec, ctx, options) if estimator_class(options.estimator).uses_observations else []
    pipe = Pipeline(ctx, options)
    for line in notes:
        warn(f"warning: {line}", quiet)
    grey = None   # the greyscale-frames test's verdict (_grey_markers), None until a frame decides
    extra = list(pipe.estimator.extra_columns)  # the estimator's own columns
    overlay = RunOverlay(out / "overlay.mp4", ctx, rec, pipe.estimator.offline) if video else None
    right_images = ctx.stereo and (pipe.needs_images or video)   # kinematics reads them for its video only
    run = RunLog()
    total = len(rec) if max_frames is None else min(len(rec), max_frames)
    bar = tqdm(total=total, desc=f"track {options.estimator}", unit="frame", file=sys.stderr,
               disable=quiet) if progress else None
    t_wall = time.perf_counter()
    with TrajectoryWriter(out, extra_columns=extra) as writer, overlay or contextlib.nullcontext():
        for frame, t_decode, t0 in read_frames(rec, max_frames, run, bar, right=right_images):
            if isinstance(frame, FrameError):   # a frame the recording could not give
                run.skipped.skip(frame, quiet)
                continue
            try:
                est, det, obs, ms = pipe.step(frame)   # checks the frame first (Pipeline.check)
            except FrameError as e:
                run.skipped.skip(e, quiet)
                continue
            if grey is None and pipe.needs_images and (
                    grey := _grey_markers(frame, ctx, options, rec.path / "robot.json")):
                notes.append(grey)
                warn(f"warning: {grey}", quiet)
            if not np.all(np.isfinite(est.E)):   # never a NaN pose row: the frame is skipped
                run.skipped.skip(FrameError(frame.index, "nonfinite_estimate",
                                            "the estimator returned a non-finite pose"), quiet)
                pipe.last_E, pipe.last_std, pipe.last_cov = ctx.handeye.copy(), None, None
                continue
            t = time.perf_counter()
            tip = tip_pixel(ctx, frame.q, est.E)
            total_ms = t_decode + sum(ms.values())
            with deferred_interrupts():   # the row and the video frame both, or neither
                writer.write(frame.index, frame.stamp, est.E, tip, total_ms, _extras(est, extra))
                if overlay is not None:   # its drawing is timed apart: not the tracking's cost
                    ms["video"] = overlay.write(frame, est, det, obs, tip, pipe.right)
            ms.update(write=1e3 * (time.perf_counter() - t) - ms.get("video", 0.0), decode=t_decode)
            run.add(frame, est.E, tip, ms, total_ms, 1e3 * (time.perf_counter() - t0) - ms.get("video", 0.0))
            run.informative.append(obs is not None and (obs.has_shaft or len(obs.markers) > 0))
        _refine(pipe, run, writer, extra)
    if ctx.stereo and rec.right_skip_warning:   # counted in metrics.json's right_skipped_reasons
        every = " (every frame: the run was mono)" if run.frames and pipe.left_only >= len(run.frames) else ""
        warn(f"warning: {rec.right_skip_warning}{every}", quiet)
    wall = time.perf_counter() - t_wall
    if bar is not None:
        bar.close()
    if overlay is not None:   # offline: drawn again with the refined poses
        overlay.finish(run.rows, run.tips, right_images, progress and not quiet)
    result = _metrics(path, out, options, rec, ctx, pipe, run, wall, notes, quiet)
    write_json(out / "metrics.json", result)   # strict JSON: NaN -> null
    require_tracked(result, out)   # no tracked frame: an error, never a silent success
    require_tool_in_front(result, Path(path) / "handeye.yaml")
    require_lock(result, path)
    return result


def near_image(camera, points: np.ndarray) -> np.ndarray:
    """Which camera-frame points (N, 3) m lie in front of the camera and project within one
    image diagonal of the image, judged by the pinhole (K) projection: outside the calibrated
    field of view the distortion polynomial folds back, putting a point just beyond a
    wide-angle view thousands of pixels away (or inside the image)."""
    p = np.asarray(points, float).reshape(-1, 3)
    ok = np.isfinite(p).all(axis=1) & (p[:, 2] > 0)
    uv = np.full((len(p), 2), np.nan)
    uv[ok] = camera.project_undistorted(p[ok])
    d, W, H = camera.diagonal, camera.width, camera.height
    return ok & (uv[:, 0] >= -d) & (uv[:, 0] < W + d) & (uv[:, 1] >= -d) & (uv[:, 1] < H + d)


def _metrics(path, out: Path, options: TrackOptions, rec: Recording, ctx: TrackingContext, pipe: Pipeline,
             run: RunLog, wall: float, notes: list[str], quiet: bool) -> dict:
    """metrics.json's content for a finished run (:func:`_result`, the run's summary, the
    estimator's report, the stretches without detections, the warnings kept)."""
    result = _result(path, out, options, rec, ctx, run, pipe.left_only, pipe.needs_images)
    result.update(run.summary(wall))
    result["estimator_report"] = pipe.estimator.report()
    warnings = rec.warnings + notes
    if pipe.needs_images:
        if hint := _correction(result, options, ctx, run):
            warnings.append(hint)
            warn(f"warning: {hint}", quiet)
        result["frames_with_detections"] = int(sum(run.informative))
        result["no_detection_stretches"] = stretches = no_detection_stretches(run.frames, run.informative)
        for a, b in stretches:
            warn(f"warning: no detections in frames {a}-{b - 1} ({b - a} frames): the pose there is the "
                  "motion model's prediction (std_* columns grow)", quiet)
    if result.get("frames_tip_in_front") and not result.get("frames_tip_in_image"):
        warnings.append(f"the tool tip projects outside the image in every tracked frame; check "
                        f"{rec.path / 'handeye.yaml'}, K1 and D1 in camera_calibration.yaml and robot.json's "
                        "tool_tip")
        warn(f"warning: {warnings[-1]}", quiet)
    if unsteady := lock_problem(result, path) or unexplained_problem(result, path):
        warnings.append(unsteady)
        warn(f"warning: {unsteady}", quiet or lock_refused(result))   # refused: said once, as the error
    result["recording_warnings"] = capped(warnings)
    return result


def _correction(result: dict, options: TrackOptions, ctx: TrackingContext, run: RunLog) -> str | None:
    """metrics.json's ``handeye_correction`` (:func:`graphtrack.estimate.prior_region.correction`
    over the frames with detections); a warning line when it lies beyond the hand-eye prior."""
    sigma_b, sigma_w = options.estimation.prior_sigma
    Es = [row[4] for row, seen in zip(run.rows, run.informative) if seen]
    c = result["handeye_correction"] = correction(Es, ctx.handeye, sigma_b, sigma_w)
    if not c or c["prior_distance"] <= PRIOR_HINT:
        return None
    wider = (math.ceil(max(sigma_b * 1e3, 0.6 * c["b_mm"])), math.ceil(max(math.degrees(sigma_w), 0.6 * c["w_deg"])))
    return (f"the tracked pose sits {c['b_mm']:.1f} mm / {c['w_deg']:.1f} deg from handeye.yaml (median over "
            f"{c['frames']} frames), beyond the hand-eye prior's 99 % region ({sigma_b * 1e3:g} mm / "
            f"{math.degrees(sigma_w):.1f} deg per axis): if the calibration is that far off, track again with "
            f"--handeye-sigma {wider[0]},{wider[1]} (docs/decisions/handeye-sigma.md)")


#: recording warnings kept in metrics.json (the rest counted)
MAX_WARNINGS = 20


def capped(lines: list[str]) -> list[str]:
    """The first MAX_WARNINGS lines, and a line counting the rest."""
    more = len(lines) - MAX_WARNINGS
    return list(lines[:MAX_WARNINGS]) + ([f"... and {more} more"] if more > 0 else [])


def _result(path, out: Path, options: TrackOptions, rec: Recording, ctx: TrackingContext, run: RunLog,
            left_only: int = 0, images: bool = True) -> dict:
    """metrics.json's run description, skip counts, tip metrics (labels.csv; with
    labels_right.csv the right-image and triangulated 3-D ones) and truth metrics (truth.csv)."""
    result = {"estimator": options.estimator, "observation": options.observation,
              "detector": options.detection.detector, "frames_tracked": len(run.frames),
              "skipped_reasons": dict(run.skipped), "frames_skipped": int(sum(run.skipped.values())),
              "frames_total": run.read, "skip_examples": run.skipped.examples}
    if rec.stereo:
        # both images used in at least one frame (not when every right image was unusable, nor
        # by an estimator without images: kinematics)
        result.update(stereo=bool(ctx.stereo) and images and left_only < len(run.frames),
                      frames_left_only=int(left_only),
                      right_skipped_reasons={k: int(v) for k, v in rec.right_skips.items()})
    tips = np.asarray(run.tips, dtype=float).reshape(-1, 2)
    if rec.robot.tool_tip is not None:   # where the estimates put the tip (require_tool_in_front)
        front = np.all(np.isfinite(tips), axis=1)
        u, v = tips[front].T
        inside = (u >= 0) & (u < ctx.camera.width) & (v >= 0) & (v < ctx.camera.height)
        near = near_image(ctx.camera, np.array([tip_point(ctx, r[2], r[4]) for r in run.rows]))
        result.update(frames_tip_in_front=int(front.sum()), frames_tip_in_image=int(inside.sum()),
                      frames_tip_near_image=int(near.sum()))
    if rec.labels is not None:
        result.update(tip_metrics(run.frames, tips, rec.labels, ctx.camera.diagonal, dict(run.skipped), run.read))
    if rec.labels_right and rec.calibration.stereo:
        tips_3d = np.array([tip_point(ctx, r[2], r[4]) for r in run.rows]).reshape(-1, 3)
        result.update(stereo_tip_metrics(rec.calibration, run.frames, tips_3d, rec.labels, rec.labels_right))
    result.update(evaluate_against_truth(path, out, rec.robot, {r[0]: r[2] for r in run.rows}))
    return result


def _extras(est: Estimate, columns: list[str]) -> dict:
    vals = dict(est.extra)
    if est.std is not None:
        vals.update({c: float(v) for c, v in zip(STD_COLUMNS, est.std)})
    return {c: vals.get(c, float("nan")) for c in columns}

