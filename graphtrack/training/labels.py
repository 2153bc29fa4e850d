"""Ground truth for the learned detector: the visible shaft edge segments and target heatmaps.

Segments. In a simulated recording camera_T_link4 = E_t . base_T_link4(q~_t)
(truth.csv's E_t, the joint readings q~_t), so the shaft cylinder (axis point
p0, unit direction d, radius r in the camera frame, from
``base_features(robot, q~).transformed(E_t)``) has its two contour generators
g_i + t d (:func:`graphtrack.geometry.cylinder.contour_generators`), which
project exactly onto the limb lines of ``shaft_lines``. The visible part of
each silhouette edge is the generator from the shaft's end near the wrist
(t = ``SHAFT_END``) back along the shaft (t = ``SHAFT_START``, the rendered
shaft's far end), clipped to the half space Z >= ``z_near``, projected to
UNDISTORTED pixels and clipped to the image rectangle
[-0.5, W - 0.5] x [-0.5, H - 0.5] (Liang-Barsky). Poses the limb projection
flags invalid (end-on, camera inside) give no segment.

Targets (at the network's reduced scale; a full-resolution pixel x maps to
x_s = (x + 0.5) s - 0.5), with d(p) the distance of pixel centre p to the
nearest segment and e(p) the distance to the nearest segment endpoint:

    line     T_L(p) = exp(-max(d(p) - 0.35, 0)^2 / (2 * 0.6^2))    (flat-topped ridge)
    junction T_J(p) = exp(-e(p)^2 / (2 * 1.0^2))

(endpoints where an edge leaves the image are junctions too).
"""
from __future__ import annotations

import numpy as np
import torch

from graphtrack.geometry.cylinder import contour_generators, project_cylinder
from graphtrack.geometry.image_scale import scale_points
from graphtrack.robot.features import base_features
from graphtrack.robot.psm import SHAFT_END

SHAFT_START = -0.45   #: m along link 4's z: the rendered shaft's far end (sim/scene.py)
LINE_HALF = 0.35      #: px (reduced): flat top of the line ridge
LINE_SIGMA = 0.6      #: px (reduced)
JUNCTION_SIGMA = 1.0  #: px (reduced)


def clip_segment(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Liang-Barsky: the part of segment a-b inside the box [lo, hi] (2-D), or None."""
    d = b - a
    t0, t1 = 0.0, 1.0
    for k in range(2):
        for p, q in ((-d[k], a[k] - lo[k]), (d[k], hi[k] - a[k])):
            if abs(p) < 1e-12:
                if q < 0:
                    return None
                continue
            r = q / p
            if p < 0:
                t0 = max(t0, r)
            else:
                t1 = min(t1, r)
            if t0 > t1:
                return None
    return a + t0 * d, a + t1 * d


def shaft_edge_segments(robot, q: np.ndarray, E: np.ndarray, K: np.ndarray, height: int, width: int,
                        z_near: float = 0.01, min_length: float = 4.0) -> np.ndarray:
    """The visible shaft edge segments (k, 4) (x1, y1, x2, y2), k <= 2, in
    undistorted px; (x1, y1) is the end nearer the wrist when it is in view."""
    feats = base_features(robot, np.asarray(q, float)).transformed(np.asarray(E, float))
    p0, d, r = feats.shaft_p0[0], feats.shaft_d[0], feats.shaft_r[0]
    if not np.all(np.isfinite(p0)) or not np.all(np.isfinite(d)):
        return np.zeros((0, 4))
    _, _, valid = project_cylinder(p0, d, r, K)
    if not bool(valid):
        return np.zeros((0, 4))
    d = d / np.linalg.norm(d)
    gens = contour_generators(p0, d, r)
    lo, hi = np.array([-0.5, -0.5]), np.array([width - 0.5, height - 0.5])
    out = []
    for g in gens:
        A, B = g + SHAFT_END * d, g + SHAFT_START * d
        za, zb = A[2], B[2]
        if za < z_near and zb < z_near:
            continue
        if za < z_near or zb < z_near:  # clip to Z >= z_near
            t = (z_near - za) / (zb - za)
            P = A + t * (B - A)
            A, B = (P, B) if za < z_near else (A, P)
        pa = K[:2, :2] @ (A[:2] / A[2]) + K[:2, 2]
        pb = K[:2, :2] @ (B[:2] / B[2]) + K[:2, 2]
        c = clip_segment(pa, pb, lo, hi)
        if c is None or np.hypot(*(c[1] - c[0])) < min_length:
            continue
        out.append(np.r_[c[0], c[1]])
    return np.array(out).reshape(-1, 4)


def to_reduced(segments: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Full-resolution segments -> reduced-scale px (x_s = (x + 0.5) s - 0.5)."""
    return scale_points(np.reshape(segments, (-1, 4)), sx, sy)


def target_maps(segments, h: int, w: int):
    """Line and junction targets (torch float (B, 2, h, w)) for reduced-scale
    segments: a tensor (B, S, 4) with NaN rows for absent segments."""
    seg = torch.as_tensor(segments, dtype=torch.float32)
    if seg.ndim == 2:
        seg = seg[None]
    B, S = seg.shape[:2]
    ys = torch.arange(h, dtype=torch.float32, device=seg.device).view(1, 1, h, 1)
    xs = torch.arange(w, dtype=torch.float32, device=seg.device).view(1, 1, 1, w)
    ok = torch.isfinite(seg).all(-1)                           # (B, S)
    s = torch.nan_to_num(seg, nan=-1e4)
    ax, ay, bx, by = (s[..., i].view(B, S, 1, 1) for i in range(4))
    dx, dy = bx - ax, by - ay
    L2 = (dx * dx + dy * dy).clamp_min(1e-9)
    t = (((xs - ax) * dx + (ys - ay) * dy) / L2).clamp(0, 1)
    dist = torch.hypot(xs - (ax + t * dx), ys - (ay + t * dy))  # (B, S, h, w)
    ea = torch.hypot(xs - ax, ys - ay)
    eb = torch.hypot(xs - bx, ys - by)
    big = torch.full_like(dist, 1e4)
    okb = ok.view(B, S, 1, 1)
    dist = torch.where(okb, dist, big).amin(1)
    e = torch.where(okb, torch.minimum(ea, eb), big).amin(1)
    line = torch.exp(-(dist - LINE_HALF).clamp_min(0) ** 2 / (2 * LINE_SIGMA ** 2))
    junc = torch.exp(-e ** 2 / (2 * JUNCTION_SIGMA ** 2))
    return torch.stack([line, junc], 1)
