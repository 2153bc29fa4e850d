"""Shared graph-building helpers of the factor-graph estimators (smoother, batch).

Conventions. gtsam perturbs a Pose3 on the right, E = Ê . Exp(xi_R) with
xi_R = (omega, v) in the BASE frame. The particle filter (and every reported
std/cov) uses the LEFT, camera-frame perturbation E = Exp(xi_L) . Ê written
translation first, (b, w). The two are related by the adjoint,

    xi_L(omega, v) = Ad_Ê xi_R,      (b, w) = (v_L, omega_L)

so a left (b, w) covariance S_L becomes the right one Ad_Ê^-1 S Ad_Ê^-T and back.
The prior and the motion model are specified in the left (b, w) stds, like the
particle filter's, and converted at the hand-eye E_0 (the error stays small,
so the adjoint at E_0 is the adjoint at E_t to within the error itself).
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.edge_bias import (bias_key, bias_prior_factor, bias_sigmas, bias_transition_factor,
                               reference_direction, transition)
from factors.limb import LimbPairing
from factors.line_parameter import line_parameter_factor
from factors.marker import marker_factor
from factors.robust import make_kernel
from factors.shaft_end import shaft_end_factor
from factors.shaft_pixels import shaft_pixels_factor
from graphtrack.estimate.observation_models import BAND_WEIGHT, END_SIGMA, PIXEL_EFFECTIVE_COUNT, set_weight
from graphtrack.detect.base import POLAR_MODELS
from graphtrack.estimate.base import STD_COLUMNS  # the extra trajectory columns (re-exported)
from graphtrack.geometry.cylinder import ShaftAxis
from graphtrack.robot.features import base_features, marker_discs

#: (b, w) <-> gtsam (omega, v) reordering
_PERM = np.array([3, 4, 5, 0, 1, 2])


def key(k: int) -> int:
    return gtsam.symbol("x", int(k))


def right_from_left_cov(E: np.ndarray, cov_bw: np.ndarray) -> np.ndarray:
    """Left (b, w) covariance at E (6x6; b m, w rad: E_true = Exp(xi) . E) -> gtsam's right
    (omega, v) covariance (E_true = E . Exp(xi_R), rotation first)."""
    S = np.asarray(cov_bw, float)[np.ix_(_PERM, _PERM)]          # (omega, v) order
    Ai = gtsam.Pose3(E).inverse().AdjointMap()
    C = Ai @ S @ Ai.T
    return 0.5 * (C + C.T)


def left_from_right_cov(E: np.ndarray, cov_right: np.ndarray) -> np.ndarray:
    """gtsam's right (omega rad, v m) covariance at E (6x6) -> the left (b m, w rad) covariance
    (:func:`right_from_left_cov` inverted)."""
    A = gtsam.Pose3(E).AdjointMap()
    C = A @ np.asarray(cov_right, float) @ A.T
    C = C[np.ix_(_PERM, _PERM)]
    return 0.5 * (C + C.T)


def left_error(E_true: np.ndarray, E_est: np.ndarray) -> np.ndarray:
    """(b m, w rad) with E_true = Exp(xi_L) . E_est: gtsam's SE(3) Logmap (translation part
    V^-1 t, not t), reordered translation first."""
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(E_true @ np.linalg.inv(E_est)))
    return np.asarray(xi)[_PERM]


def gaussian_bw(E: np.ndarray, sigma_b: float, sigma_w: float):
    """gtsam Gaussian noise for isotropic left (b, w) stds at E, in gtsam's right coordinates."""
    S = np.diag([sigma_b ** 2] * 3 + [sigma_w ** 2] * 3)
    return gtsam.noiseModel.Gaussian.Covariance(right_from_left_cov(E, S))


@dataclass
class FactorOptions:
    """Measurement models of one frame's detections.

    pixel_sigma: px across the line, per shaft pixel.
    line_sigma_rho (px) / line_sigma_theta (rad): a detected polar line (rho, theta).
    marker_sigma: px per marker detection.
    marker_gate: association gate in detection-image px; the gate used is
    marker_gate * gate_scale (60, not the paper's 20: start-up hand-eye errors).
    gate_scale: full-size px per detection-image px (the pipeline passes 1 / its
    detection scale, 2 at 1080x1920 detected at half size).
    marker_discs: a marker with a ``radius`` is a painted disc, predicted by its
    image centroid (:mod:`graphtrack.geometry.painted_marker`); False: points.
    robust: "cauchy" | "huber" | "none"; robust_k its width in whitened units
    (None: 2.0 Cauchy / 1.345 Huber).
    markers: use marker detections.
    max_pixels: at most this many pixels per edge set (deterministic stride; 0 = all).
    pixel_effective_count n: an m > n pixel set's cost is weighted n / m, so it
    counts as n independent pixels (0: every pixel counts; the robust kernel still
    judges each pixel on pixel_sigma).
    band_weight: the weight of the pixel set of an edge the detector's refinement did
    not move onto the image's edge (``Observation.bands``), times the above.
    edge_bias: carry the detector's edge-bias vector b = (lateral, lateral slope,
    width, width slope, end offset) px (:mod:`factors.edge_bias`), a Gauss-Markov process
    with stationary stds edge_bias_sigma_lateral / _lateral_slope / _width /
    _width_slope / _end (px) and time constant edge_bias_tau (s), one vector per
    edge_bias_every frames. Pixel sets are on it; so are the polar models' lines (the
    smoother's only once settled, ``line_bias`` of :func:`frame_factor_groups`) and, in
    stereo frames, the shaft end (``end_offset``).
    shaft_end_sigma (px) / shaft_end_robust: the detected shaft end's residual along
    the shaft's image and its kernel (:mod:`factors.shaft_end`; Huber at 1.345 sigma,
    as the other factors: a false end pulls with a bounded force).

    Why these defaults, with measurements: docs/decisions/pixel-effective-count.md,
    edge-bias-state.md, marker-gate.md, painted-disc-markers.md, band-weight.md.
    """

    pixel_sigma: float = 1.5
    line_sigma_rho: float = 3.0
    line_sigma_theta: float = 0.01
    marker_sigma: float = 2.0
    marker_gate: float = 60.0
    marker_discs: bool = True
    robust: str = "huber"
    robust_k: float | None = None
    markers: bool = True
    max_pixels: int = 0
    pixel_effective_count: float = PIXEL_EFFECTIVE_COUNT
    band_weight: float = BAND_WEIGHT
    gate_scale: float = 1.0
    edge_bias: bool = True
    edge_bias_sigma_lateral: float = 0.3
    edge_bias_sigma_lateral_slope: float = 0.3
    edge_bias_sigma_width: float = 1.5
    edge_bias_sigma_width_slope: float = 1.5
    edge_bias_sigma_end: float = 1.0
    edge_bias_tau: float = 2.0
    edge_bias_every: int = 5
    shaft_end_sigma: float = END_SIGMA
    shaft_end_robust: str = "huber"

    @property
    def kernel(self):
        return make_kernel(self.robust, self.robust_k)

    @property
    def edge_bias_period(self) -> int:
        """Frames per edge-bias vector: frame k's is vector k // period."""
        return max(int(self.edge_bias_every), 1)

    @property
    def edge_bias_sigmas(self) -> np.ndarray:
        return bias_sigmas(self.edge_bias_sigma_lateral, self.edge_bias_sigma_lateral_slope,
                           self.edge_bias_sigma_width, self.edge_bias_sigma_width_slope,
                           self.edge_bias_sigma_end)


def edge_bias_factors(k: int, dt: float | None, opts: FactorOptions) -> list:
    """The edge-bias state's factors of frame k: its prior when k starts the chain
    (``dt`` None), else the Gauss-Markov transition from frame k - 1 over ``dt`` s."""
    if dt is None:
        return [bias_prior_factor(k, opts.edge_bias_sigmas)]
    return [bias_transition_factor(k - 1, k, transition(dt, opts.edge_bias_tau), opts.edge_bias_sigmas)]


def frame_factors(k: int, q: np.ndarray, observation, robot, K: np.ndarray,
                  opts: FactorOptions, E_ref: np.ndarray | None = None) -> list:
    """The measurement factors of frame k (may be empty: no detections):
    :func:`frame_factor_groups`' shaft factors, then its marker factors."""
    shaft, markers = frame_factor_groups(k, q, observation, robot, K, opts, E_ref)
    return shaft + markers


def frame_factor_groups(k: int, q: np.ndarray, observation, robot, K: np.ndarray,
                        opts: FactorOptions,
                        E_ref: np.ndarray | None = None, pose_key: int | None = None,
                        line_bias: bool = True, extrinsic: np.ndarray | None = None,
                        end_offset: bool = False, features=None) -> tuple[list, list]:
    """The measurement factors of frame k as (shaft factors, marker factors).

    Pixel models: one :func:`factors.shaft_pixels.shaft_pixels_factor` per
    edge; polar models: one :func:`factors.line_parameter.line_parameter_factor`
    per detected line; plus one :func:`factors.marker.marker_factor` for all
    marker detections. The shaft axis / marker points are the forward
    kinematics of this frame's readings q (fixed data). ``E_ref`` (the
    estimator's hand-eye prior E_0) orients the edge-bias slope terms
    (:func:`factors.edge_bias.reference_direction`), the same way in every frame.
    ``line_bias``: with the edge-bias state, whether the detected lines of the polar
    models are on it (the smoother holds them off it until its start-up has
    settled, :mod:`graphtrack.estimate.smoother`); the pixel sets always are.
    ``extrinsic``: the observing camera from the left one (the stereo right camera:
    right_T_left, with K its K2, E_ref its camera's right_T_left . E_0;
    :mod:`factors.error_function`). Its edges are on the same edge-bias vector as the
    left image's (:mod:`graphtrack.estimate.stereo` says why).
    ``end_offset``: with the edge-bias state, whether the shaft end is on its end offset
    e (stereo frames: :mod:`graphtrack.estimate.stereo` says why); else e = 0.
    """
    if observation is None:
        return [], []
    out = []
    has_shaft = observation.has_shaft
    want_markers = opts.markers and len(observation.markers) > 0
    if not has_shaft and not want_markers:
        return out, []
    F = base_features(robot, np.asarray(q, float)) if features is None else features
    kern = opts.kernel
    x = key(k) if pose_key is None else pose_key
    b = bias_key(k // opts.edge_bias_period) if opts.edge_bias else None
    model = observation.model
    if has_shaft and len(F.shaft_r):
        axis = ShaftAxis.make(F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0])
        direction = None            # orients the bias slopes, the same way in every frame
        if b is not None and E_ref is not None:
            direction = reference_direction(np.asarray(E_ref, float), F.shaft_p0[0], F.shaft_d[0], K)
        if model in POLAR_MODELS or (len(observation.lines) and not observation.pixels):
            lines = np.asarray(observation.lines, float).reshape(-1, 2)
            lines = lines[np.all(np.isfinite(lines), axis=1)]
            pairing = LimbPairing() if len(lines) > 1 else None
            lb = b if line_bias else None
            for line in lines:
                out.append(line_parameter_factor(x, line, axis, K, opts.line_sigma_rho,
                                                 opts.line_sigma_theta, kern, pairing, lb, direction,
                                                 extrinsic))
        else:
            sets = [(np.asarray(px, float).reshape(-1, 2), band)
                    for px, band in zip(observation.pixels, observation.pixel_bands)]
            sets = [(px[np.all(np.isfinite(px), axis=1)], band) for px, band in sets]
            sets = [(px, band) for px, band in sets if len(px)]
            pairing = LimbPairing() if len(sets) > 1 else None
            for px, band in sets:
                if opts.max_pixels and len(px) > opts.max_pixels:
                    px = px[np.linspace(0, len(px) - 1, opts.max_pixels).astype(int)]
                w = set_weight(len(px), band, opts.pixel_effective_count, opts.band_weight)
                f = shaft_pixels_factor(x, px, axis, K, opts.pixel_sigma, kern, pairing, w, b, direction,
                                        extrinsic)
                if f is not None:
                    out.append(f)
        out += _end_factors(x, observation, robot, q, F, K, opts, extrinsic, b if end_offset else None)
    if want_markers and len(F.points):
        mk = np.asarray(observation.markers, float).reshape(-1, 2)
        mk = mk[np.all(np.isfinite(mk), axis=1)]
        discs = marker_discs(robot, F) if opts.marker_discs else None
        f = marker_factor(x, mk, F.points, K, opts.marker_sigma, opts.marker_gate * opts.gate_scale, kern,
                          discs, extrinsic)
        if f is not None:
            return out, [f]
    return out, []


def _end_factors(x: int, observation, robot, q, F, K, opts: FactorOptions, extrinsic, b) -> list:
    """The shaft-end factor of a frame whose observation has a detected end (else none),
    on the end offset of the edge-bias vector ``b`` (a key; None: without the state)."""
    end = np.asarray(observation.shaft_end, float).reshape(-1, 4)
    sf = robot.shaft_features[0]
    if len(end) == 0 or sf.end is None:
        return []
    return [shaft_end_factor(x, end[0, :2], end[0, 2:], F.shaft_end[0], F.shaft_d[0], F.shaft_r[0], K,
                             opts.shaft_end_sigma, make_kernel(opts.shaft_end_robust), extrinsic, b)]


def split_options(options: dict) -> tuple[FactorOptions, dict]:
    """Pull the FactorOptions fields out of an estimator's **options."""
    fields = FactorOptions.__dataclass_fields__
    fo = FactorOptions(**{k: v for k, v in options.items() if k in fields})
    rest = {k: v for k, v in options.items() if k not in fields}
    return fo, rest


def estimate_extra(cov_bw: np.ndarray | None) -> dict[str, float]:
    if cov_bw is None:
        return {c: float("nan") for c in STD_COLUMNS}
    std = np.sqrt(np.clip(np.diag(cov_bw), 0.0, None))
    return {c: float(s) for c, s in zip(STD_COLUMNS, std)}
