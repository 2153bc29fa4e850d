"""The tracking loop: recording -> undistort -> detect -> observe -> estimate -> write.

``track`` streams a recording frame by frame through one estimator and writes
trajectory.csv / trajectory.tum row by row (flushed, so an interruption loses
nothing already computed), then metrics.json when labels.csv exists. A bad
frame (corrupt image, NaN joints, ...) is skipped, warned about and counted in
metrics.json; bad recordings raise InputError before anything is written.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from graphtrack.detect import make_detector, observe
from graphtrack.detect.options import MAX_DETECT_WIDTH, OBSERVATION, DetectionOptions
from graphtrack.errors import FrameError, InputError
from graphtrack.estimate import estimator_class, make_estimator
from graphtrack.estimate.base import STD_COLUMNS, Estimate
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.eval.metrics import evaluate_against_truth, tip_metrics
from graphtrack.eval.overlay import OverlayWriter
from graphtrack.eval.robustness import no_detection_stretches
from graphtrack.eval.stereo import stereo_tip_metrics
from graphtrack.io.context import TrackingContext
from graphtrack.io.frame import Frame
from graphtrack.io.run_output import write_json
from graphtrack.io.outdir import writable_dir
from graphtrack.io.recording import Recording, open_recording
from graphtrack.io.topics import TopicSelection
from graphtrack.io.trajectory import TrajectoryWriter
from graphtrack.robot.features import base_features, shaft_lines

STAGES = ("decode", "undistort", "detect", "observe", "estimate", "write")
ESTIMATOR = "smoother"   #: the default estimator: the fixed-lag smoother


@dataclass(frozen=True)
class TrackOptions:
    """Everything that selects one tracking run (also the key of a study cell).

    estimator: a name of :data:`graphtrack.estimate.ESTIMATORS`; observation:
    the observation model (:data:`graphtrack.detect.base.OBSERVATION_MODELS`);
    seed: of the observation's RANSAC draws (the estimator's own is in
    ``estimation``; the CLI and the studies set both from one seed); tip_feature:
    a point feature to evaluate instead of robot.json's tool_tip; stereo: use the
    right image too when the recording has one (False: ``--mono``, left only).
    """

    estimator: str = ESTIMATOR
    observation: str = OBSERVATION
    detection: DetectionOptions = field(default_factory=DetectionOptions)
    estimation: EstimatorOptions = field(default_factory=EstimatorOptions)
    seed: int = 0
    tip_feature: str | None = None
    stereo: bool = True


#: the widest association gate (px at full size), see Pipeline.gate
MAX_GATE_PX = 150.0


def auto_detect_scale(width: int, max_width: int = MAX_DETECT_WIDTH) -> float:
    """Detection runs on the undistorted image scaled to at most ``max_width`` px wide
    (1080x1920 recordings are detected at half size; smaller ones at full size)."""
    return 1.0 if width <= max_width else max_width / float(width)


class Pipeline:
    """One frame at a time: undistort, detect, build the observation, estimate.

    ``step(frame)`` returns (Estimate, Detection | None, Observation | None,
    per-stage milliseconds). The detector is gated with the shaft edges
    predicted from the previous estimate and the current joint readings.

    Stereo (``ctx.stereo``): the right image is undistorted and detected too, gated
    with the shaft predicted through the right camera (right_T_left . E, K2) and the
    left image's gate widths, and its observation goes to the estimator as
    ``right``; its (Detection, Observation) are kept in ``right`` (both None for a
    left-only frame), the per-stage milliseconds are those of both images. A frame
    whose right image is missing or corrupt is a left-only update, counted in
    ``left_only``. (The learned detector runs each image through the net on its own:
    one forward pass of both was slower, docs/decisions/stereo-detection.md.)
    """

    def __init__(self, ctx: TrackingContext, options: TrackOptions):
        self.ctx = ctx
        self.options = options
        det = options.detection
        self.scale = det.scale or auto_detect_scale(ctx.camera.width)
        self.detect_camera = ctx.camera if self.scale == 1.0 else ctx.camera.scaled(self.scale)
        self.stereo = bool(ctx.stereo)
        self.detect_right = None if not self.stereo else (
            ctx.right if self.scale == 1.0 else ctx.right.scaled(self.scale))
        self.right = (None, None)     # the last frame's right (Detection, Observation)
        self.left_only = 0            # stereo frames updated without their right image
        cls = estimator_class(options.estimator)
        self.needs_images = cls.uses_observations
        kw = options.estimation.keywords(options.estimator)
        self.detector = None
        if self.needs_images:
            # marker gates are tuned in detection pixels (an image <= 960 px wide); the
            # estimators see full-size pixels
            kw.update(markers=det.markers, gate_scale=1.0 / self.scale)
            self.detector = make_detector(det.detector, **det.detector_keywords())
        self.estimator = make_estimator(options.estimator, ctx, **kw)
        self.last_E = ctx.handeye.copy()
        self.last_std = None          # nothing known before the first estimate: widest gate
        self._predicted = None        # (frame, E, camera-frame features) of _predicted_features
        self.rng = np.random.default_rng(options.seed)

    def predicted_lines(self, frame: Frame, right: bool = False) -> np.ndarray | None:
        """Shaft edges (2, 2) (rho, theta) from the last estimate and this frame's
        readings, in the undistorted pixels of the (possibly scaled) detection image
        (``right``: of the right image, through right_T_left . E and K2)."""
        if not self.ctx.robot.shaft_features:
            return None
        feats, K = self._predicted_features(frame), self.detect_camera.K
        if right:
            feats, K = feats.transformed(self.ctx.right_T_left), self.detect_right.K
        rho, theta, valid = shaft_lines(feats, K)
        return np.stack([rho, theta], -1) if bool(valid) else None

    def _predicted_features(self, frame: Frame):
        """This frame's features in the camera frame of the last estimate, computed once
        per (frame, estimate) for predicted_lines and gate."""
        c = self._predicted
        if c is None or c[0] is not frame or c[1] is not self.last_E:
            c = self._predicted = (frame, self.last_E,
                                   base_features(self.ctx.robot, frame.q).transformed(self.last_E))
        return c[2]

    def gate(self, frame: Frame):
        """The association gates for this frame, widened with the estimate's uncertainty.

        The predicted shaft moves in the image by about
        s = f (|(std_bx, std_by)| / Z + |(std_wx, std_wy)|) px for the left (b, w)
        standard deviations of the last estimate (Z: depth of the shaft point, f
        in detection pixels); the offset gate is max(configured, 3 s), at most
        ``MAX_GATE_PX``. Before the first estimate (nothing known yet) it is
        MAX_GATE_PX. Why: docs/decisions/gate-follows-covariance.md.
        """
        if self.detector is None or not self.ctx.robot.shaft_features:
            return None
        base = self.detector.association
        if base is None:
            return None
        std = self.last_std
        if std is None:
            widest = MAX_GATE_PX * self.scale
        else:
            if not np.all(np.isfinite(std)):
                return None
            z = self._predicted_features(frame).shaft_p0[0, 2]
            f = self.detect_camera.K[0, 0]
            s = f * (np.hypot(std[0], std[1]) / max(z, 1e-3) + np.hypot(std[3], std[4]))
            widest = min(3.0 * s, MAX_GATE_PX * self.scale)
        if widest <= base.max_offset:
            return None
        return dataclasses.replace(base, max_offset=float(widest))

    def _image(self, image: np.ndarray, camera, lines, gate, ms: dict):
        """Undistort, detect and observe one image; (Detection, Observation) in
        full-size pixels; adds the stages' milliseconds to ``ms``."""
        det = self.options.detection
        t = time.perf_counter()
        und = camera.undistort(image, self.scale)
        ms["undistort"] = ms.get("undistort", 0.0) + 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        detection = self.detector.detect(und, lines, gate)
        ms["detect"] = ms.get("detect", 0.0) + 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        observation = observe.make_observation(detection, self.options.observation, alpha=det.alpha,
                                               beta=det.beta, use_markers=det.markers, rng=self.rng)
        observation = observe.scale_observation(observation, 1.0 / self.scale)  # full-size pixels
        detection = observe.scale_detection(detection, 1.0 / self.scale)
        ms["observe"] = ms.get("observe", 0.0) + 1e3 * (time.perf_counter() - t)
        return detection, observation

    def step(self, frame: Frame):
        ms = {}
        detection = observation = None
        self.right = (None, None)
        if self.needs_images:
            gate = self.gate(frame)
            detection, observation = self._image(frame.image, self.ctx.camera, self.predicted_lines(frame),
                                                 gate, ms)
            if self.stereo and frame.image_right is not None:
                self.right = self._image(frame.image_right, self.ctx.right,
                                         self.predicted_lines(frame, right=True), gate, ms)
            elif self.stereo:
                self.left_only += 1
        t = time.perf_counter()
        estimate = (self.estimator.step(frame, observation, self.right[1]) if self.stereo
                    else self.estimator.step(frame, observation))
        ms["estimate"] = 1e3 * (time.perf_counter() - t)
        self.last_E = estimate.E
        self.last_std = None if estimate.std is None else np.asarray(estimate.std, float)
        return estimate, detection, observation, ms


def tip_point(ctx: TrackingContext, q: np.ndarray, E: np.ndarray) -> np.ndarray:
    """The tool tip in the LEFT camera frame, E . tip(q), (3,) m (NaN if the robot has none)."""
    feats = base_features(ctx.robot, q)
    return np.full(3, np.nan) if feats.tip is None else np.asarray(feats.transformed(E).tip, float)


def tip_pixel(ctx: TrackingContext, q: np.ndarray, E: np.ndarray) -> np.ndarray:
    """The tool tip projected into the RAW (distorted) left image, (2,) px (NaN if none/behind)."""
    tip = tip_point(ctx, q, E)
    if not tip[2] > 0:
        return np.full(2, np.nan)
    return ctx.camera.project_raw(tip)


def _evaluated_tip(rec: Recording, tip_feature: str | None):
    """The robot with the point that is evaluated as the tool tip (format doc: robot.json's
    ``tool_tip``; when it is missing, evaluation must be told which point feature to use)."""
    robot = rec.robot
    if tip_feature:
        names = {p.name: p for p in robot.point_features}
        if tip_feature not in names:
            raise InputError(f"--tip-feature: {rec.path / 'robot.json'} has no point feature {tip_feature!r} "
                             f"(it has: {', '.join(names) or 'none'})")
        return dataclasses.replace(robot, tool_tip=names[tip_feature])
    if robot.tool_tip is None and rec.labels:
        raise InputError(f"{rec.path / 'robot.json'}: no tool_tip, so labels.csv cannot be scored; "
                         "name the point feature to evaluate with --tip-feature NAME")
    return robot


def _open(path: str | Path, options: TrackOptions, quiet: bool,
          topics: TopicSelection) -> tuple[Recording, TrackingContext]:
    """The recording (checked; its warnings printed unless quiet) and its tracking context."""
    rec = open_recording(path, topics=topics)
    if rec.robot.has_gripper and not rec.has_jaw:
        raise InputError(f"{rec.path}: robot.json says has_gripper but the recording has no jaw readings "
                         "(/dvrk/PSM1/state_jaw_current or the joints.csv 'jaw' column); the tool tip "
                         "would be wrong without them")
    for w in rec.warnings:
        _warn(f"warning: {w}", quiet)
    rec.robot = _evaluated_tip(rec, options.tip_feature)
    cal = rec.calibration
    if options.stereo and rec.stereo:
        return rec, TrackingContext(rec.robot, cal.left, rec.handeye, cal.right, cal.right_T_left)
    return rec, TrackingContext(rec.robot, cal.left, rec.handeye)


def _warn(message: str, quiet: bool) -> None:
    if not quiet:
        print(f"graphtrack: {message}", file=sys.stderr)


def _untrackable(frame: Frame, n_joints: int, last_stamp: float | None) -> FrameError | None:
    """Why a decoded frame cannot be tracked (a FrameError with its skip reason), or None:
    a joint vector of another length or with NaN, or a stamp not after the last tracked one."""
    if len(frame.q) != n_joints or not np.all(np.isfinite(frame.q)):
        return FrameError(frame.index, "joint_count" if len(frame.q) != n_joints else "nan_joints",
                          f"joint vector has {len(frame.q)} values (finite: {bool(np.all(np.isfinite(frame.q)))}), "
                          f"expected {n_joints}")
    if not (np.isfinite(frame.stamp) and (last_stamp is None or frame.stamp > last_stamp)):
        return FrameError(frame.index, "stamp_order",
                          f"stamp {frame.stamp!r} is not after the previous frame's {last_stamp!r}")
    return None


class SkipCounter(Counter):
    """Skipped frames per reason, and the first message of each (metrics.json ``skip_examples``)."""

    def __init__(self):
        super().__init__()
        self.examples: dict[str, str] = {}

    def skip(self, error: FrameError, quiet: bool) -> None:
        """Count a skipped frame, keep its reason's first message, warn unless quiet."""
        self[error.reason] += 1
        self.examples.setdefault(error.reason, str(error))
        _warn(f"warning: skipping {error}", quiet)


@dataclass
class _Run:
    """What one tracking run has collected so far: per tracked frame its index, tip
    pixel and (index, stamp, q, total ms, E) row; per-stage and per-frame milliseconds;
    the skip reasons; frames read (tracked or skipped)."""

    frames: list = field(default_factory=list)
    tips: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    stage_ms: dict = field(default_factory=lambda: {s: [] for s in STAGES})
    frame_ms: list = field(default_factory=list)
    skipped: SkipCounter = field(default_factory=SkipCounter)
    read: int = 0
    informative: list = field(default_factory=list)   # per tracked frame: a shaft or marker detected

    @property
    def last_stamp(self) -> float | None:
        return self.rows[-1][1] if self.rows else None

    def add(self, frame: Frame, E: np.ndarray, tip: np.ndarray, ms: dict, total_ms: float,
            frame_ms: float) -> None:
        for s in STAGES:
            self.stage_ms[s].append(ms.get(s, 0.0))
        self.frame_ms.append(frame_ms)
        self.frames.append(frame.index)
        self.tips.append(tip)
        self.rows.append((frame.index, frame.stamp, frame.q, total_ms, E))

    def summary(self, wall: float) -> dict:
        """Frame counts, median ms per stage, fps over the wall time and the steady state:
        every per-frame cost (decode ... write) of frames 1.. (frame 0 also pays the
        start-up: the bag's joint pass, first use of the detector), no finish()."""
        out = {"timing_ms_median": {s: float(np.median(v)) if v else 0.0 for s, v in self.stage_ms.items()},
               "fps": float(len(self.frames) / wall) if wall > 0 else float("nan")}
        steady = self.frame_ms[1:] if len(self.frame_ms) > 1 else self.frame_ms
        out["frame_ms_mean"] = float(np.mean(steady)) if steady else float("nan")
        out["fps_steady"] = float(1e3 / np.mean(steady)) if steady else float("nan")
        out["wall_s"] = float(wall)
        return out


def _frames(rec: Recording, max_frames: int | None, run: _Run, bar):
    """(item, decode ms, start time) for up to ``max_frames`` recording items, counted in run.read."""
    it = iter(rec.frames())
    while max_frames is None or run.read < max_frames:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        run.read += 1
        if bar is not None:
            bar.update(1)
        yield item, 1e3 * (time.perf_counter() - t0), t0


def _refine(pipe: Pipeline, run: _Run, writer: TrajectoryWriter, extra: list[str]) -> None:
    """An offline estimator's refined estimates replace every streamed row and tip."""
    refined = pipe.estimator.finish()
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
          topics: TopicSelection = TopicSelection()) -> dict:
    """Run one estimator over a recording; write the outputs into ``out``; return metrics.

    ``topics``: the arm and bag topics to read (default: detected, :mod:`graphtrack.io.topics`).

    The returned dict is metrics.json's content plus ``timing`` (median ms
    per stage) and ``fps``.
    """
    rec, ctx = _open(path, options, quiet, topics)
    out = writable_dir(out)
    pipe = Pipeline(ctx, options)
    extra = list(pipe.estimator.extra_columns)  # the estimator's own columns
    overlay = OverlayWriter(out / "overlay.mp4", ctx, labels=rec.labels,
                            labels_right=rec.labels_right) if video else None
    run = _Run()
    total = len(rec) if max_frames is None else min(len(rec), max_frames)
    bar = tqdm(total=total, desc=f"track {options.estimator}", unit="frame", file=sys.stderr,
               disable=quiet) if progress else None
    t_wall = time.perf_counter()
    with TrajectoryWriter(out, extra_columns=extra) as writer:
        for item, t_decode, t0 in _frames(rec, max_frames, run, bar):
            if not isinstance(item, FrameError):
                item = _untrackable(item, rec.robot.n_joints, run.last_stamp) or item
            if isinstance(item, FrameError):
                run.skipped.skip(item, quiet)
                continue
            frame = item
            est, det, obs, ms = pipe.step(frame)
            if not np.all(np.isfinite(est.E)):   # never a NaN pose row: the frame is skipped
                run.skipped.skip(FrameError(frame.index, "nonfinite_estimate",
                                            "the estimator returned a non-finite pose"), quiet)
                pipe.last_E, pipe.last_std = ctx.handeye.copy(), None
                continue
            t = time.perf_counter()
            tip = tip_pixel(ctx, frame.q, est.E)
            total_ms = t_decode + sum(ms.values())
            writer.write(frame.index, frame.stamp, est.E, tip, total_ms, _extras(est, extra))
            if overlay is not None:
                overlay.write(frame, est, det, obs, tip, pipe.right)
            ms["write"] = 1e3 * (time.perf_counter() - t)
            ms["decode"] = t_decode
            run.add(frame, est.E, tip, ms, total_ms, 1e3 * (time.perf_counter() - t0))
            run.informative.append(obs is not None and (obs.has_shaft or len(obs.markers) > 0))
        _refine(pipe, run, writer, extra)
    if ctx.stereo and rec.right_skip_warning:   # counted in metrics.json's right_skipped_reasons
        _warn(f"warning: {rec.right_skip_warning}", quiet)
    wall = time.perf_counter() - t_wall
    if bar is not None:
        bar.close()
    if overlay is not None:
        overlay.close()
    result = _result(path, out, options, rec, ctx, run, pipe.left_only)
    result.update(run.summary(wall))
    if pipe.needs_images:
        result["no_detection_stretches"] = stretches = no_detection_stretches(run.frames, run.informative)
        for a, b in stretches:
            _warn(f"warning: no detections in frames {a}-{b - 1} ({b - a} frames): the pose there is the "
                  "motion model's prediction (std_* columns grow)", quiet)
    write_json(out / "metrics.json", result)   # strict JSON: NaN -> null
    return result


def _result(path, out: Path, options: TrackOptions, rec: Recording, ctx: TrackingContext, run: _Run,
            left_only: int = 0) -> dict:
    """metrics.json's run description, skip counts, tip metrics (labels.csv; with
    labels_right.csv the right-image and triangulated 3-D ones) and truth metrics (truth.csv)."""
    result = {"estimator": options.estimator, "observation": options.observation,
              "detector": options.detection.detector, "frames_tracked": len(run.frames),
              "skipped_reasons": dict(run.skipped), "frames_skipped": int(sum(run.skipped.values())),
              "frames_total": run.read, "skip_examples": run.skipped.examples}
    if rec.stereo:
        result.update(stereo=bool(ctx.stereo), frames_left_only=int(left_only),
                      right_skipped_reasons={k: int(v) for k, v in rec.right_skips.items()})
    if rec.labels is not None:
        tips = np.asarray(run.tips, dtype=float).reshape(-1, 2)
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
