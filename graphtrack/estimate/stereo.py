"""Both endoscope images in one update: the right camera's observation terms.

A stereo rig's right camera sees the tool through

    right_T_base = right_T_left . E,          right_T_left = [R T; 0 1]  (metres)

(camera_calibration.yaml's R, T), so the right image observes the SAME lumped error
E_t as the left one; nothing about E changes, only the camera its terms project
through (K2, and the rig's extrinsics before E).

Factor graphs (smoother, batch): the frame's right-image detections become the same
factors as the left's (shaft pixels or lines, markers) on the same pose key, their
error functions evaluated at right_T_left . E (:mod:`factors.error_function`); for
gtsam's right perturbation the Jacobians carry over unchanged. Particle filter: the
log-likelihood is the sum of both images' terms (the images are independent given
E), the right one from the same vectorised models with each particle's pose mapped
by right_T_left (:func:`graphtrack.estimate.pf.projection.to_camera`).

The right image's edges are on the SAME edge-bias vector b_j as the left's
(:mod:`factors.edge_bias`; the slope terms oriented in each image by its own
camera's reference direction): the same detector on two nearly identical views
errs alike, and a shared vector cannot absorb the disparity (an offset common to
both images does not change it). Measurements: docs/decisions/stereo-edge-bias.md.

In a stereo frame the shaft end (in both images) is on the edge-bias vector's end
offset e too (:mod:`factors.shaft_end`): an end detector errs along the shaft by
nearly the same amount in every frame, and with the disparity fixing the depth, that
error, averaged over frames as if it were white, became the largest in the 3-D tip.
A mono frame keeps e = 0: there the end is what holds the depth / width-bias ridge
that the edge-bias state leaves loose, and with e free the estimate drifts along it
(docs/decisions/end-offset-state.md).
"""
from __future__ import annotations

import numpy as np

from graphtrack.estimate.graph import FactorOptions, frame_factor_groups


def stereo_factor_groups(k: int, q: np.ndarray, observation, right, ctx, K: np.ndarray,
                         opts: FactorOptions, E_ref: np.ndarray | None = None,
                         pose_key: int | None = None, line_bias: bool = True, features=None) -> tuple[list, list]:
    """The measurement factors of frame k from both images as (shaft factors, marker
    factors): :func:`graphtrack.estimate.graph.frame_factor_groups` of the left
    ``observation`` (camera K), then, when ``right`` is given and ``ctx`` is stereo,
    those of the right observation through ctx.right's K2 and ctx.right_T_left, both
    images' shaft ends on the end offset (module doc). A frame without a right
    observation (missing or corrupt right image) is left-only. features: the frame's
    base_features(ctx.robot, q) when the caller has them."""
    both = right is not None and ctx.stereo
    shaft, markers = frame_factor_groups(k, q, observation, ctx.robot, K, opts, E_ref, pose_key, line_bias,
                                         end_offset=both, features=features)
    if both:
        ref = None if E_ref is None else ctx.right_T_left @ np.asarray(E_ref, float)
        rs, rm = frame_factor_groups(k, q, right, ctx.robot, np.asarray(ctx.right.K, float), opts,
                                     ref, pose_key, line_bias, extrinsic=ctx.right_T_left, end_offset=True,
                                     features=features)
        shaft, markers = shaft + rs, markers + rm
    return shaft, markers


def stereo_frame_factors(k: int, q: np.ndarray, observation, right, ctx, K: np.ndarray,
                         opts: FactorOptions, E_ref: np.ndarray | None = None) -> list:
    """:func:`stereo_factor_groups`' shaft factors, then its marker factors."""
    shaft, markers = stereo_factor_groups(k, q, observation, right, ctx, K, opts, E_ref)
    return shaft + markers
