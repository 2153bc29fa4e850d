"""Painted markers: discs on the shaft's surface, and the centroid of their image.

A marker painted on the insertion shaft is a disc of radius R_m (m, measured
on the surface) around the surface point P_k of robot.json's point feature.
The detector reports the centroid of the marker's image blob, which is not the
projection pi(P_k) of its centre: the disc wraps around the cylinder (radius
r), so the side facing the camera covers more pixels than the side turning
away, and near a silhouette part of it is hidden. For a disc seen at an angle
gamma from face-on the centroid sits about 1.5 <delta^2> r sin(gamma) towards
the face-on meridian (delta = s / r, the angle a surface point sits from the
centre; <delta^2> = R_m^2 / (4 r^2)), more when partly hidden. Decision and
measurements: docs/decisions/painted-disc-markers.md.

Surface samples. The disc is cut into the cells of an n x n grid over its
bounding square, in surface coordinates (arc length s around the shaft, h along
its axis); the cell centres inside the disc (s^2 + h^2 <= R_m^2) are the
samples, each standing for the same surface area. With the axis point p0, unit
direction d, the radial unit vector n_k of P_k and t_k = d x n_k, sample
(s, h) of marker k is the surface point and outward normal

    X = p0 + ((P_k - p0) . d + h) d + r (cos(s/r) n_k + sin(s/r) t_k)
    N = cos(s/r) n_k + sin(s/r) t_k.

Centroid. A surface element dA at camera point X with outward normal N covers
an image area (px^2) of fx fy g / Z^3 dA, g = max(0, -N . X) (its projection
on the z = 1 plane; g = 0: facing away). The blob's centroid is the
area-weighted mean of the samples' pixels,

    c = sum_i w_i pi(X_i) / sum_i w_i,     w_i = g_i / Z_i^3,

undefined when every sample faces away (the marker is hidden). Occlusion by
other parts of the tool is not modelled.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from graphtrack.geometry import pinhole


@lru_cache(maxsize=8)
def _unit_pattern(n: int) -> tuple[np.ndarray, np.ndarray]:
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    s, h = np.meshgrid(g, g)
    inside = s ** 2 + h ** 2 <= 1.0
    s, h = s[inside], h[inside]
    s.flags.writeable = h.flags.writeable = False
    return s, h


def disc_pattern(radius: float, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """Surface offsets (s, h) (S,) each, m, of a disc of ``radius`` m: the centres of
    the n x n grid cells over its bounding square that lie inside it (equal areas)."""
    s, h = _unit_pattern(int(n))
    return s * float(radius), h * float(radius)


def on_surface(points: np.ndarray, p0: np.ndarray, d: np.ndarray, r: float,
               tol: float = 0.05) -> np.ndarray:
    """(M,) bool: the points (M, 3) lie on the cylinder (p0, unit d, radius r), to
    within ``tol`` r of its surface."""
    v = np.asarray(points, float) - p0
    rad = v - (v @ d)[:, None] * d
    return np.abs(np.linalg.norm(rad, axis=1) - r) <= tol * r


def painted_disc(points: np.ndarray, p0: np.ndarray, d: np.ndarray, r: float,
                 radius, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples X (M, S, 3) and outward normals N (M, S, 3) of discs of
    ``radius`` m (a number or one per point) painted around the surface points
    (M, 3) of the cylinder (axis point p0, unit direction d, radius r), all in
    one frame (see the module doc)."""
    P = np.asarray(points, float).reshape(-1, 3)
    p0, d = np.asarray(p0, float), np.asarray(d, float)
    su, hu = _unit_pattern(int(n))
    rad = np.broadcast_to(np.asarray(radius, float), (len(P),))[:, None]
    s, h = rad * su, rad * hu                                   # (M, S)
    v = P - p0
    ax = v @ d
    nk = v - ax[:, None] * d
    nk /= np.linalg.norm(nk, axis=1, keepdims=True)
    tk = np.stack([d[1] * nk[:, 2] - d[2] * nk[:, 1], d[2] * nk[:, 0] - d[0] * nk[:, 2],
                   d[0] * nk[:, 1] - d[1] * nk[:, 0]], -1)         # d x n_k
    a = s / r
    N = np.cos(a)[..., None] * nk[:, None, :] + np.sin(a)[..., None] * tk[:, None, :]
    X = p0 + (ax[:, None] + h)[..., None] * d + r * N
    return X, N


def disc_centroid(X: np.ndarray, N: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Image centroids (..., 2) px of discs sampled at camera points X (..., S, 3)
    with outward normals N (..., S, 3) (see the module doc); NaN where hidden."""
    X, N = np.asarray(X, float), np.asarray(N, float)
    g = np.maximum(-(N * X).sum(-1), 0.0)
    w = g * pinhole.inverse_depth(X[..., 2], 0.0) ** 3      # 0 behind the camera
    u = pinhole.project(K, X, behind=0.0)                  # finite; weighted 0 behind the camera
    W = w.sum(-1)
    c = (w[..., None] * u).sum(-2) / np.where(W > 0, W, 1.0)[..., None]
    return np.where((W > 0)[..., None], c, np.nan)
