"""The tracking loop: recording -> undistort -> detect -> observe -> estimate -> write.

``track`` streams a recording frame by frame through one estimator and writes
trajectory.csv / trajectory.tum row by row (flushed, so an interruption loses
nothing already computed), then metrics.json when labels.csv exists. A bad
frame (corrupt image, NaN joints, ...) is skipped, warned about and counted in
metrics.json; bad recordings raise InputError before anything is written.
"""
from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphtrack.errors import FrameError, InputError
from graphtrack.estimate import make_estimator
from graphtrack.estimate.base import STD_COLUMNS, Estimate, Frame
from graphtrack.estimate.context import TrackingContext
from graphtrack.io.topics import TopicSelection
from graphtrack.robot.features import base_features, shaft_lines

STAGES = ("decode", "undistort", "detect", "observe", "estimate", "write")


@dataclass
class TrackOptions:
    """Everything that selects one tracking run (also the key of a study cell)."""

    estimator: str = "kinematics"
    observation: str = "line-intensities"
    detector: str = "learned"
    markers: bool = True
    estimator_options: dict = field(default_factory=dict)
    detector_options: dict = field(default_factory=dict)
    alpha: float = 10.0
    beta: float = 0.9
    seed: int = 0
    detect_scale: float | None = None  # None: auto, detect at most 960 px wide
    tip_feature: str | None = None     # a point feature to evaluate instead of robot.json's tool_tip


#: the widest association gate (px at full size), see Pipeline.gate
MAX_GATE_PX = 150.0


def auto_detect_scale(width: int, max_width: int = 960) -> float:
    """Detection runs on the undistorted image scaled to at most ``max_width`` px wide
    (1080x1920 recordings are detected at half size; smaller ones at full size)."""
    return 1.0 if width <= max_width else max_width / float(width)


class Pipeline:
    """One frame at a time: undistort, detect, build the observation, estimate.

    ``step(frame)`` returns (Estimate, Detection | None, Observation | None,
    per-stage milliseconds). The detector is gated with the shaft edges
    predicted from the previous estimate and the current joint readings.
    """

    def __init__(self, ctx: TrackingContext, options: TrackOptions):
        self.ctx = ctx
        self.options = options
        self.scale = options.detect_scale or auto_detect_scale(ctx.camera.width)
        self.detect_camera = ctx.camera if self.scale == 1.0 else ctx.camera.scaled(self.scale)
        opts = dict(options.estimator_options)
        if options.estimator != "kinematics":
            opts.setdefault("observation", options.observation)
            opts.setdefault("markers", options.markers)
            # marker gates are tuned in detection pixels (an image <= 960 px wide); the
            # estimators see full-size pixels
            opts.setdefault("gate_scale", 1.0 / self.scale)
        self.estimator = make_estimator(options.estimator, ctx, **opts)
        self.needs_images = getattr(self.estimator, "uses_observations", True)
        self.detector = None
        if self.needs_images:
            from graphtrack.detect import make_detector
            from graphtrack.detect import observe

            self.detector = make_detector(options.detector, **options.detector_options)
            self.observe = observe
        self.last_E = ctx.handeye.copy()
        self.last_std = None          # nothing known before the first estimate: widest gate
        self._predicted = None        # (frame, E, camera-frame features) of _predicted_features
        self.rng = np.random.default_rng(options.seed)

    def predicted_lines(self, frame: Frame) -> np.ndarray | None:
        """Shaft edges (2, 2) (rho, theta) from the last estimate and this frame's
        readings, in the undistorted pixels of the (possibly scaled) detection image."""
        if not self.ctx.robot.shaft_features:
            return None
        rho, theta, valid = shaft_lines(self._predicted_features(frame), self.detect_camera.K)
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
        MAX_GATE_PX. A fixed 40 px gate at a start-up 42 px off kept a
        tuning recording's true edges out for 8 frames.
        """
        from dataclasses import replace

        base = getattr(self.detector, "association", None)
        if base is None or not self.ctx.robot.shaft_features:
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
        return replace(base, max_offset=float(widest))

    def step(self, frame: Frame):
        ms = {}
        detection = observation = None
        if self.needs_images:
            observe = self.observe
            t = time.perf_counter()
            und = self.ctx.camera.undistort(frame.image, self.scale)
            ms["undistort"] = 1e3 * (time.perf_counter() - t)
            t = time.perf_counter()
            detection = self.detector.detect(und, self.predicted_lines(frame), self.gate(frame))
            ms["detect"] = 1e3 * (time.perf_counter() - t)
            t = time.perf_counter()
            observation = observe.make_observation(detection, self.options.observation,
                                                   alpha=self.options.alpha, beta=self.options.beta,
                                                   use_markers=self.options.markers, rng=self.rng)
            observation = observe.scale_observation(observation, 1.0 / self.scale)  # full-size pixels
            detection = observe.scale_detection(detection, 1.0 / self.scale)
            ms["observe"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        estimate = self.estimator.step(frame, observation)
        ms["estimate"] = 1e3 * (time.perf_counter() - t)
        self.last_E = estimate.E
        self.last_std = None if estimate.std is None else np.asarray(estimate.std, float)
        return estimate, detection, observation, ms


def tip_pixel(ctx: TrackingContext, q: np.ndarray, E: np.ndarray) -> np.ndarray:
    """The tool tip projected into the RAW (distorted) left image, (2,) px (NaN if none/behind)."""
    feats = base_features(ctx.robot, q)
    if feats.tip is None:
        return np.full(2, np.nan)
    tip = feats.transformed(E).tip
    if tip[2] <= 0:
        return np.full(2, np.nan)
    return ctx.camera.project_raw(tip)


def _evaluated_tip(rec, tip_feature: str | None):
    """The robot with the point that is evaluated as the tool tip (format doc: robot.json's
    ``tool_tip``; when it is missing, evaluation must be told which point feature to use)."""
    import dataclasses

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


def track(path: str | Path, out: str | Path, options: TrackOptions, video: bool = False,
          progress: bool = True, max_frames: int | None = None, quiet: bool = False,
          topics: TopicSelection = TopicSelection()) -> dict:
    """Run one estimator over a recording; write the outputs into ``out``; return metrics.

    ``topics``: the arm and bag topics to read (default: detected, :mod:`graphtrack.io.topics`).

    The returned dict is metrics.json's content plus ``timing`` (median ms
    per stage) and ``fps``.
    """
    from graphtrack.eval.metrics import evaluate_against_truth, tip_metrics
    from graphtrack.io.outdir import writable_dir
    from graphtrack.io.recording import open_recording
    from graphtrack.io.run_output import write_json
    from graphtrack.io.trajectory import TrajectoryWriter

    rec = open_recording(path, topics=topics)
    if rec.robot.has_gripper and not rec.has_jaw:
        raise InputError(f"{rec.path}: robot.json says has_gripper but the recording has no jaw readings "
                         "(/dvrk/PSM1/state_jaw_current or the joints.csv 'jaw' column); the tool tip "
                         "would be wrong without them")
    for w in rec.warnings:
        if not quiet:
            print(f"graphtrack: warning: {w}", file=sys.stderr)
    rec.robot = _evaluated_tip(rec, options.tip_feature)
    ctx = TrackingContext(rec.robot, rec.calibration.left, rec.handeye)
    out = writable_dir(out)
    pipe = Pipeline(ctx, options)
    extra = list(getattr(pipe.estimator, "extra_columns", ()))  # the estimator's own columns
    overlay = None
    if video:
        from graphtrack.eval.overlay import OverlayWriter

        overlay = OverlayWriter(out / "overlay.mp4", ctx, labels=rec.labels)
    skipped = SkipCounter()
    frames, tips, stage_ms, rows, frame_ms = [], [], {s: [] for s in STAGES}, [], []
    total = len(rec) if max_frames is None else min(len(rec), max_frames)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=f"track {options.estimator}", unit="frame", file=sys.stderr,
                   disable=quiet)
    t_wall = time.perf_counter()
    with TrajectoryWriter(out, extra_columns=extra) as writer:
        it = iter(rec.frames())
        n = 0
        while max_frames is None or n < max_frames:
            t0 = time.perf_counter()
            try:
                item = next(it)
            except StopIteration:
                break
            t_decode = 1e3 * (time.perf_counter() - t0)
            n += 1
            if bar is not None:
                bar.update(1)
            if not isinstance(item, FrameError) and (len(item.q) != rec.robot.n_joints
                                                     or not np.all(np.isfinite(item.q))):
                item = FrameError(item.index, "joint_count" if len(item.q) != rec.robot.n_joints
                                  else "nan_joints", f"joint vector has {len(item.q)} values (finite: "
                                  f"{bool(np.all(np.isfinite(item.q)))}), expected {rec.robot.n_joints}")
            if not isinstance(item, FrameError) and not (np.isfinite(item.stamp) and
                                                         (not rows or item.stamp > rows[-1][1])):
                item = FrameError(item.index, "stamp_order", f"stamp {item.stamp!r} is not after the "
                                  f"previous frame's {rows[-1][1] if rows else None!r}")
            if isinstance(item, FrameError):
                skip(skipped, item, quiet)
                continue
            frame = item
            est, det, obs, ms = pipe.step(frame)
            if not np.all(np.isfinite(est.E)):   # never a NaN pose row: the frame is skipped
                skip(skipped, FrameError(frame.index, "nonfinite_estimate", "the estimator returned a "
                                         "non-finite pose"), quiet)
                pipe.last_E, pipe.last_std = ctx.handeye.copy(), None
                continue
            t = time.perf_counter()
            tip = tip_pixel(ctx, frame.q, est.E)
            total_ms = t_decode + sum(ms.values())
            extras = _extras(est, extra)
            writer.write(frame.index, frame.stamp, est.E, tip, total_ms, extras)
            if overlay is not None:
                overlay.write(frame, est, det, obs, tip)
            ms["write"] = 1e3 * (time.perf_counter() - t)
            frame_ms.append(1e3 * (time.perf_counter() - t0))
            ms["decode"] = t_decode
            for s in STAGES:
                stage_ms[s].append(ms.get(s, 0.0))
            frames.append(frame.index)
            tips.append(tip)
            rows.append((frame.index, frame.stamp, frame.q, total_ms, est.E))
        refined = pipe.estimator.finish() if hasattr(pipe.estimator, "finish") else None
        if refined is not None:
            tips = []
            new_rows = []
            for (fi, stamp, q, ms_, E0), est in zip(rows, refined):
                E = est.E if np.all(np.isfinite(est.E)) else E0   # a non-finite refinement keeps the streamed pose
                tip = tip_pixel(ctx, q, E)
                tips.append(tip)
                new_rows.append((fi, stamp, E, tip, ms_, _extras(est, extra)))
            writer.rewrite_all(new_rows)
    wall = time.perf_counter() - t_wall
    if bar is not None:
        bar.close()
    if overlay is not None:
        overlay.close()
    tips_arr = np.asarray(tips, dtype=float).reshape(-1, 2)
    result = {"estimator": options.estimator, "observation": options.observation,
              "detector": options.detector, "frames_tracked": len(frames),
              "skipped_reasons": dict(skipped), "frames_skipped": int(sum(skipped.values())),
              "frames_total": n, "skip_examples": skipped.examples}
    if rec.labels is not None:
        result.update(tip_metrics(frames, tips_arr, rec.labels, ctx.camera.diagonal, dict(skipped), n))
    result.update(evaluate_against_truth(path, out, rec.robot, {r[0]: r[2] for r in rows}))
    result["timing_ms_median"] = {s: float(np.median(v)) if v else 0.0 for s, v in stage_ms.items()}
    result["fps"] = float(len(frames) / wall) if wall > 0 else float("nan")
    # steady state: every per-frame cost (decode ... write) of frames 1.. (frame 0 also
    # pays the start-up: the bag's joint pass, first use of the detector), no finish()
    steady = frame_ms[1:] if len(frame_ms) > 1 else frame_ms
    result["frame_ms_mean"] = float(np.mean(steady)) if steady else float("nan")
    result["fps_steady"] = float(1e3 / np.mean(steady)) if steady else float("nan")
    result["wall_s"] = float(wall)
    write_json(out / "metrics.json", result)   # strict JSON: NaN -> null
    return result


class SkipCounter(Counter):
    """Skipped frames per reason, and the first message of each (metrics.json
    ``skip_examples``)."""

    def __init__(self):
        super().__init__()
        self.examples: dict[str, str] = {}


def skip(skipped: SkipCounter, error: FrameError, quiet: bool) -> None:
    """Count a skipped frame, keep its reason's first message, warn unless quiet."""
    skipped[error.reason] += 1
    skipped.examples.setdefault(error.reason, str(error))
    if not quiet:
        print(f"graphtrack: warning: skipping {error}", file=sys.stderr)


def _extras(est: Estimate, columns: list[str]) -> dict:
    vals = dict(est.extra)
    if est.std is not None:
        vals.update({c: float(v) for c, v in zip(STD_COLUMNS, est.std)})
    return {c: vals.get(c, float("nan")) for c in columns}
