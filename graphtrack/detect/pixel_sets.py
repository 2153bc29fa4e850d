"""The method's heatmap pixel sets around detected shaft edges.

With the line heatmap H in [0, 1]^{H x W} (undistorted image; pixel p = (x, y)
is the centre of column x, row y), a detected edge with endpoints e^a, e^b
(px), radius alpha (px, default 10) and heatmap threshold beta (default 0.90):

    endpoint set  E_e(e)        = {p : |p - e| <= alpha,             H(p) >= beta}
    line set      E_l(e^a, e^b) = {p : dist(p, [e^a, e^b]) <= alpha, H(p) >= beta}

where dist(p, [e^a, e^b]) is the Euclidean distance to the closed segment.
Each set is computed on the bounding box of its region only: the box is cut
from H, thresholded at beta, and only the surviving pixels are tested for
distance (no per-pixel Python). Sets are returned as (m, 2) float (x, y),
row-major order (by y, then x).

``heatmap=None`` means H = 1 everywhere: the sets become the discs / capsules
themselves (clipped to ``shape`` when it is given, else to x, y >= 0 only).

A heatmap found at a reduced scale places its band a pixel or more off the image's
edge; when the sub-pixel refinement has moved the edge's segment onto the image's
edge, :func:`carry_to_segment` moves the set rigidly onto the segment's line
(why, with measurements: docs/decisions/pixel-sets-follow-refinement.md).
"""
from __future__ import annotations

import cv2
import numpy as np

ALPHA = 10.0  #: px, the method's set radius
BETA = 0.90   #: the method's heatmap threshold
#: rad: a set whose own line is further from the segment's is not a band along it and is not carried
MAX_CARRY_ANGLE = 0.05


def _box(xmin: float, xmax: float, ymin: float, ymax: float,
         shape: tuple[int, int] | None) -> tuple[int, int, int, int] | None:
    """Integer pixel box [x0, x1) x [y0, y1) covering the real interval, clipped."""
    if not np.all(np.isfinite([xmin, xmax, ymin, ymax])):
        return None
    x0, y0 = max(0, int(np.ceil(xmin))), max(0, int(np.ceil(ymin)))
    x1, y1 = int(np.floor(xmax)) + 1, int(np.floor(ymax)) + 1
    if shape is not None:
        x1, y1 = min(x1, int(shape[1])), min(y1, int(shape[0]))
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, x1, y0, y1


def _candidates(heatmap: np.ndarray | None, box, beta: float) -> np.ndarray:
    """Pixels (n, 2) float (x, y) of the box with H >= beta (all of them if H is None)."""
    x0, x1, y0, y1 = box
    if heatmap is None:
        ys, xs = np.mgrid[y0:y1, x0:x1]
        return np.stack([xs.ravel(), ys.ravel()], 1).astype(float)
    # cv2.findNonZero: the same pixels in the same row-major order as np.nonzero, 3x faster
    nz = cv2.findNonZero((heatmap[y0:y1, x0:x1] >= beta).view(np.uint8))
    if nz is None:
        return np.zeros((0, 2))
    p = nz.reshape(-1, 2).astype(float)
    p[:, 0] += x0
    p[:, 1] += y0
    return p


def _shape(heatmap, shape):
    return heatmap.shape[:2] if heatmap is not None else shape


def endpoint_set(heatmap: np.ndarray | None, e: np.ndarray, alpha: float = ALPHA,
                 beta: float = BETA, shape: tuple[int, int] | None = None) -> np.ndarray:
    """E_e(e): pixels within alpha px of the endpoint e = (x, y) with H >= beta -> (m, 2)."""
    e = np.asarray(e, float).ravel()[:2]
    box = _box(e[0] - alpha, e[0] + alpha, e[1] - alpha, e[1] + alpha, _shape(heatmap, shape))
    if box is None:
        return np.zeros((0, 2))
    p = _candidates(heatmap, box, beta)
    d2 = np.sum((p - e) ** 2, axis=1)
    return p[d2 <= alpha * alpha]


def endpoints_set(heatmap: np.ndarray | None, segment: np.ndarray, alpha: float = ALPHA,
                  beta: float = BETA, shape: tuple[int, int] | None = None) -> np.ndarray:
    """E_e(e^a) U E_e(e^b) of a segment (x1, y1, x2, y2), without duplicates -> (m, 2)."""
    s = np.asarray(segment, float).ravel()
    a = endpoint_set(heatmap, s[:2], alpha, beta, shape)
    b = endpoint_set(heatmap, s[2:4], alpha, beta, shape)
    if len(a) == 0 or len(b) == 0:
        return a if len(b) == 0 else b
    # drop from b the pixels already in a (the discs overlap on short segments)
    b = b[np.sum((b - s[:2]) ** 2, axis=1) > alpha * alpha]
    p = np.concatenate([a, b])
    order = np.lexsort((p[:, 0], p[:, 1]))
    return p[order]


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (px) of points (P, 2) to the closed segment [a, b]."""
    p = np.asarray(points, float)
    a = np.asarray(a, float)
    ab = np.asarray(b, float) - a
    L2 = float(ab @ ab)
    t = np.zeros(len(p)) if L2 <= 0 else np.clip((p - a) @ ab / L2, 0.0, 1.0)
    return np.hypot(p[:, 0] - a[0] - t * ab[0], p[:, 1] - a[1] - t * ab[1])


def line_set(heatmap: np.ndarray | None, segment: np.ndarray, alpha: float = ALPHA,
             beta: float = BETA, shape: tuple[int, int] | None = None) -> np.ndarray:
    """E_l(e^a, e^b): pixels within alpha px of the segment (x1, y1, x2, y2) with
    H >= beta -> (m, 2)."""
    s = np.asarray(segment, float).ravel()
    a, b = s[:2], s[2:4]
    box = _box(min(a[0], b[0]) - alpha, max(a[0], b[0]) + alpha,
               min(a[1], b[1]) - alpha, max(a[1], b[1]) + alpha, _shape(heatmap, shape))
    if box is None:
        return np.zeros((0, 2))
    p = _candidates(heatmap, box, beta)
    if len(p) == 0:
        return p
    return p[segment_distance(p, a, b) <= alpha]


def carry_to_segment(points: np.ndarray, segment: np.ndarray, max_angle: float = MAX_CARRY_ANGLE) -> np.ndarray:
    """The pixel set (m, 2) moved rigidly so that its own total-least-squares line lies on
    the line of ``segment`` (x1, y1, x2, y2), px.

    The set's TLS line passes through its centroid c along the principal direction
    d_s = (cos a, sin a), a = atan2(2 S_xy, S_xx - S_yy) / 2 (S: the centred second
    moments), unit normal n_s = (-sin a, cos a). With the segment's unit normal n_g
    (oriented so that n_g . n_s >= 0) and a point e^a on it, every pixel is rotated
    about c by the angle phi from n_s to n_g, then shifted by -(n_g . c - n_g . e^a) n_g.
    The pixels' count, their spread about the line and their places along it are kept.
    Returned unchanged: fewer than 2 pixels, a degenerate segment, a set without a
    direction (principal second moments within a factor 3 of each other: a blob), or
    |phi| > ``max_angle`` (the set is then not a band along the segment).
    """
    p = np.asarray(points, float).reshape(-1, 2)
    s = np.asarray(segment, float).ravel()
    a, d = s[:2], s[2:4] - s[:2]
    length = float(np.hypot(d[0], d[1]))
    if len(p) < 2 or not np.isfinite(length) or length <= 0:
        return p
    c = p.mean(axis=0)
    q = p - c
    sxx, sxy, syy = q[:, 0] @ q[:, 0], q[:, 0] @ q[:, 1], q[:, 1] @ q[:, 1]
    if not np.hypot(sxx - syy, 2.0 * sxy) >= 0.5 * (sxx + syy):   # (l1 - l2) / (l1 + l2) < 1/2; NaN
        return p
    ang = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    n_s = np.array([-np.sin(ang), np.cos(ang)])
    n_g = np.array([-d[1], d[0]]) / length
    if n_g @ n_s < 0:
        n_g = -n_g
    phi = float(np.arctan2(n_s[0] * n_g[1] - n_s[1] * n_g[0], n_s @ n_g))
    if not abs(phi) <= max_angle:
        return p
    cp, sp = np.cos(phi), np.sin(phi)
    return q @ np.array([[cp, sp], [-sp, cp]]) + (c - (n_g @ c - n_g @ a) * n_g)
