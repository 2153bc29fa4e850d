"""One frame through the tracking pipeline: undistort, detect, observe, estimate.

:class:`TrackOptions` selects a run (estimator, observation model, detection and
estimation options); :class:`Pipeline` steps one frame at a time, gating the
detector with the shaft predicted from the last estimate; :func:`tip_pixel` is the
evaluated tool tip of an estimate.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from graphtrack.detect import make_detector, observe, shaft_end
from graphtrack.detect.options import MAX_DETECT_WIDTH, OBSERVATION, DetectionOptions
from graphtrack.estimate import estimator_class, make_estimator
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.estimate.gating import gate_along
from graphtrack.estimate.observation_models import END_SIGMA
from graphtrack.geometry.shaft_end import end_pixel, front_point
from graphtrack.io.context import TrackingContext
from graphtrack.errors import FrameError, InputError, check_seed
from graphtrack.io.frame import Frame
from graphtrack.io.frame_checks import frame_problem, right_problem
from graphtrack.io.joint_units import joint_bounds
from graphtrack.robot.features import base_features, shaft_lines

ESTIMATOR = "smoother"   #: the default estimator: the fixed-lag smoother


@dataclass(frozen=True)
class TrackOptions:
    """Everything that selects one tracking run (also the key of a study cell).

    estimator: a name of :data:`graphtrack.estimate.ESTIMATORS`; observation:
    the observation model (:data:`graphtrack.detect.base.OBSERVATION_MODELS`);
    seed: of the observation's RANSAC draws (the estimator's own is in
    ``estimation``; the CLI and the studies set both from one seed); tip_feature:
    a point feature to evaluate instead of robot.json's tool_tip (:func:`track` applies
    it; a :class:`Pipeline` and :func:`tip_pixel` use ``ctx.robot.tool_tip``, which a
    caller replaces the same way); stereo: use the
    right image too when the recording has one (False: ``--mono``, left only).
    """

    estimator: str = ESTIMATOR
    observation: str = OBSERVATION
    detection: DetectionOptions = field(default_factory=DetectionOptions)
    estimation: EstimatorOptions = field(default_factory=EstimatorOptions)
    seed: int = 0
    tip_feature: str | None = None
    stereo: bool = True

    def check(self) -> TrackOptions:
        """Raise InputError naming the option of a value out of range (the command line's
        checks, for a caller in Python); return self."""
        from graphtrack.detect.base import OBSERVATION_MODELS
        from graphtrack.estimate import ESTIMATORS

        if self.estimator not in ESTIMATORS:
            raise InputError(f"estimator {self.estimator!r}: choose from {', '.join(ESTIMATORS)}")
        if self.observation not in OBSERVATION_MODELS:
            raise InputError(f"observation {self.observation!r}: choose from {', '.join(OBSERVATION_MODELS)}")
        check_seed(self.seed)
        if not isinstance(self.stereo, (bool, np.bool_)):
            raise InputError(f"stereo must be True or False (False: --mono), got {self.stereo!r}")
        self.detection.check()
        self.estimation.check()
        return self


#: the widest association gate (px at full size), see Pipeline.gate
MAX_GATE_PX = 150.0
#: the narrowest shaft-end gate (px at full size), see Pipeline.end_gate
END_GATE_MIN_PX = 20.0


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
        options.check()
        if ctx.stereo and not options.stereo:   # --mono: the right camera is not used
            ctx = dataclasses.replace(ctx, right=None, right_T_left=None)
        self.ctx = ctx
        self.options = options
        self.last_stamp: float | None = None   # of the last frame stepped (stamps must increase)
        self._joint_bounds = joint_bounds(ctx.robot, ctx.robot.n_dh)
        det = options.detection
        self.scale = det.scale or auto_detect_scale(ctx.camera.width)
        self.detect_camera = ctx.camera if self.scale == 1.0 else ctx.camera.scaled(self.scale)
        self.stereo = bool(ctx.stereo)
        self.detect_right = None if not self.stereo else (
            ctx.right if self.scale == 1.0 else ctx.right.scaled(self.scale))
        self.right = (None, None)     # the last frame's right (Detection, Observation)
        self.left_only = 0            # stereo frames updated without their right image
        #: of those, the frames whose right image was refused, by reason (io.frame_checks.right_problem)
        self.right_refused = {"image_size": 0, "image_format": 0, "same_as_left": 0}
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
        self.last_cov = None          # its (b, w) covariance: the end gate
        self._predicted = None        # (frame, E, camera-frame features) of _predicted_features
        self._end_gate = float("inf")  # px, this frame's end_gate
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

    def _image(self, image: np.ndarray, camera, detect_camera, lines, gate, ms: dict, predicted_end=None):
        """Undistort, detect and observe one image; (Detection, Observation) in
        full-size pixels; adds the stages' milliseconds to ``ms``.

        A detector that reads raw frames (``raw_input``, the learned one) gets the raw
        image, resized to the detection size (cv2.INTER_AREA), and ``detect_camera``,
        and undistorts only what it uses; the others get the undistorted image."""
        det = self.options.detection
        t = time.perf_counter()
        raw = getattr(self.detector, "raw_input", False)
        if not raw:
            img = camera.undistort(image, self.scale)
        elif self.scale != 1.0:
            img = cv2.resize(image, (detect_camera.width, detect_camera.height), interpolation=cv2.INTER_AREA)
        else:
            img = image
        ms["undistort"] = ms.get("undistort", 0.0) + 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        detection = (self.detector.detect(img, lines, gate, camera=detect_camera) if raw
                     else self.detector.detect(img, lines, gate))
        ms["detect"] = ms.get("detect", 0.0) + 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        observation = observe.make_observation(detection, self.options.observation, alpha=det.alpha,
                                               beta=det.beta, use_markers=det.markers, rng=self.rng)
        observation = observe.scale_observation(observation, 1.0 / self.scale)  # full-size pixels
        detection = observe.scale_detection(detection, 1.0 / self.scale)
        end = self._end(image, camera, detection, predicted_end)
        if end is not None:
            observation.shaft_end = end
        ms["observe"] = ms.get("observe", 0.0) + 1e3 * (time.perf_counter() - t)
        return detection, observation

    def predicted_end(self, frame: Frame, right: bool = False):
        """(pixel (2,), direction (2,)): where the shaft visibly ends at the last estimate
        (:func:`graphtrack.geometry.shaft_end.front_point`) and the unit image direction
        along the shaft towards it (full-size undistorted px; ``right``: in the right
        image); None when robot.json gives no shaft end or shaft-end detection is off."""
        shafts = self.ctx.robot.shaft_features
        if not self.options.detection.shaft_end or not shafts or shafts[0].end is None:
            return None
        feats = self._predicted_features(frame)
        K = self.ctx.camera.K
        if right:
            feats, K = feats.transformed(self.ctx.right_T_left), self.ctx.right.K
        return end_pixel(feats.shaft_end[0], feats.shaft_d[0], shafts[0].radius, K)

    def end_gate(self, frame: Frame, predicted) -> float:
        """px: how far along the shaft's image a detected end may lie from the predicted
        one (``predicted``: :meth:`predicted_end` of this frame, None without one):
        max(``END_GATE_MIN_PX``, 3 sqrt(d^T P d + s^2)), P the image covariance of
        the predicted end's front point under the last estimate's (b, w) covariance, d
        the shaft's image direction there, s the end's detection noise (``END_SIGMA``)
        (:func:`graphtrack.estimate.gating.gate_along`); inf before the first estimate,
        without a covariance, or with the end behind the camera."""
        cov = self.last_cov
        if cov is None or predicted is None or not np.all(np.isfinite(cov)):
            return float("inf")
        feats = self._predicted_features(frame)
        P3 = front_point(feats.shaft_end[0], feats.shaft_d[0], self.ctx.robot.shaft_features[0].radius)
        return gate_along(P3, predicted[1], self.ctx.camera.K, cov, END_SIGMA, END_GATE_MIN_PX)

    def _end(self, image, camera, detection, predicted) -> np.ndarray | None:
        """The shaft end (1, 4) found on ``image`` (:mod:`graphtrack.detect.shaft_end`)
        within the end gate of the predicted one, or None."""
        if predicted is None or len(detection.shaft_lines) != 2:
            return None
        end = shaft_end.locate(shaft_end.raw_sampler(image, camera), detection.shaft_lines,
                               detection.shaft_segments, predicted[1], predicted=predicted[0])
        if end is None or abs(end.direction @ (end.point - predicted[0])) > self._end_gate:
            return None
        return np.concatenate([end.point, end.direction])[None]

    def check(self, frame: Frame) -> FrameError | None:
        """Why ``frame`` cannot be tracked (a FrameError with its skip reason, as a recording's
        frames are checked: :func:`graphtrack.io.frame_checks.frame_problem`, and a stamp
        not after the last stepped frame's), or None."""
        robot, cam = self.ctx.robot, self.ctx.camera
        problem = frame_problem(frame, robot.n_dh, (cam.height, cam.width), self._joint_bounds, robot.has_gripper)
        if problem is not None:
            return problem
        if isinstance(frame.stamp, bool) or not (isinstance(frame.stamp, (int, float, np.number))
                                                 and np.isfinite(frame.stamp)):
            return FrameError(frame.index, "stamp_order", f"stamp {frame.stamp!r} is not a finite number (seconds)")
        if self.last_stamp is not None and not frame.stamp > self.last_stamp:
            return FrameError(frame.index, "stamp_order",
                              f"stamp {frame.stamp!r} is not after the previous frame's {self.last_stamp!r}")
        return None

    def step(self, frame: Frame):
        """Track one frame: (Estimate, Detection | None, Observation | None, per-stage ms).

        Raises the FrameError of :meth:`check` for a frame that cannot be tracked (nothing
        changes then); a right image of another size, not 8-bit BGR or a copy of the left one
        is not used (a left-only update, counted in ``right_refused`` by reason). An offline
        estimator (``batch``) answers each frame with its online estimate; :meth:`finish`
        returns the refined ones."""
        problem = self.check(frame)
        if problem is not None:
            raise problem
        why = right_problem(frame, (self.ctx.camera.height, self.ctx.camera.width)) if self.stereo else None
        if why is not None:
            self.right_refused[why] += 1
            frame = dataclasses.replace(frame, image_right=None)
        ms = {}
        detection = observation = None
        self.right = (None, None)
        if self.needs_images:
            gate, end = self.gate(frame), self.predicted_end(frame)
            self._end_gate = self.end_gate(frame, end)
            detection, observation = self._image(frame.image, self.ctx.camera, self.detect_camera,
                                                 self.predicted_lines(frame), gate, ms, end)
            if self.stereo and frame.image_right is not None:
                self.right = self._image(frame.image_right, self.ctx.right, self.detect_right,
                                         self.predicted_lines(frame, right=True), gate, ms,
                                         self.predicted_end(frame, right=True))
            elif self.stereo:
                self.left_only += 1
        t = time.perf_counter()
        estimate = (self.estimator.step(frame, observation, self.right[1]) if self.stereo
                    else self.estimator.step(frame, observation))
        ms["estimate"] = 1e3 * (time.perf_counter() - t)
        self.last_E = estimate.E
        self.last_std = None if estimate.std is None else np.asarray(estimate.std, float)
        self.last_cov = None if estimate.cov is None else np.asarray(estimate.cov, float)
        self.last_stamp = frame.stamp
        return estimate, detection, observation, ms

    def finish(self):
        """After the last frame: an offline estimator's refined estimates, one per stepped
        frame in order (``batch``); None for an online one (its answers are final)."""
        return self.estimator.finish()


def tip_point(ctx: TrackingContext, q: np.ndarray, E: np.ndarray) -> np.ndarray:
    """The tool tip in the LEFT camera frame, E . tip(q), (3,) m (NaN if the robot has none).

    q: the full joint vector (``Frame.q``: the DH joints, then the jaw for a tool with a
    gripper); E: 4x4, metres. ValueError naming the expected length or shape otherwise."""
    robot = ctx.robot
    q = np.asarray(q, dtype=float)
    if q.shape != (robot.n_joints,):
        raise ValueError(f"q has shape {q.shape}, expected ({robot.n_joints},): {robot.n_dh} DH joints"
                         f"{' then the jaw (Frame.q)' if robot.has_gripper else ''}")
    if np.shape(E) != (4, 4):
        raise ValueError(f"E has shape {np.shape(E)}, expected a 4x4 transform (metres)")
    feats = base_features(robot, q)
    return np.full(3, np.nan) if feats.tip is None else np.asarray(feats.transformed(E).tip, float)


def tip_pixel(ctx: TrackingContext, q: np.ndarray, E: np.ndarray) -> np.ndarray:
    """The tool tip projected into the RAW (distorted) left image, (2,) px (NaN if none/behind)."""
    tip = tip_point(ctx, q, E)
    if not tip[2] > 0:
        return np.full(2, np.nan)
    return ctx.camera.project_raw(tip)
