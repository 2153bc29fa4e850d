"""Sub-pixel refinement of a detected shaft edge on the full-resolution image.

The learned detector finds the shaft edges on a 1/4-scale heatmap, so its
segments are good to a pixel or two of the full-resolution image: on the
benchmark recordings their lines were 1.2 px and 0.19 deg off the true limbs
(median; Canny's sub-pixel lines 0.6 px). The silhouette itself is sharp in
the image, so each associated segment is moved onto the image's edge:

1. the grey image (Gaussian blur ``blur`` px, 3x3 Sobel / 8: grey levels per
   px) gives the gradient g, only in the segments' bounding box;
2. along the segment a = e^a, b = e^b (direction d, normal n), every ``step``
   px from ``end_margin`` px inside each end (the end face's corner and the
   image border are not edge), the signed normal gradient g(p + t n) . n is
   sampled (bilinear) for t in [-search, search] every 0.5 px;
3. the edge's polarity (dark shaft on a lighter background or the reverse) is
   the majority sign of the rows' strongest samples; each row's peak of the
   gradient of that polarity, if inside the window and at least
   ``min_strength`` of the rows' median peak, is located to sub-pixel by a
   parabola through it and its neighbours;
4. a total-least-squares line through the peaks, refitted on those within
   ``inlier`` px of it, is the refined edge when it keeps at least
   ``min_fraction`` of the rows (and ``min_samples``); the refined segment is
   e^a, e^b projected on it. Otherwise the segment is kept as detected.

Coordinates are undistorted full-resolution pixels (pixel centres at
integers, as everywhere in graphtrack).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from graphtrack.detect.ransac import fit_line_tls


@dataclass
class SubpixelConfig:
    """Refinement settings (px of the full-resolution image, fractions)."""

    search: float = 3.0        #: px either side of the detected segment
    step: float = 4.0          #: px between samples along it
    end_margin: float = 6.0    #: px left out at each end
    blur: float = 1.0          #: Gaussian sigma before the gradient
    min_strength: float = 0.3  #: a row's peak vs the median peak
    inlier: float = 1.0        #: px, TLS inlier band
    min_fraction: float = 0.5  #: rows that must support the refined line
    min_samples: int = 8


def edge_gradient(gray: np.ndarray, box: tuple[int, int, int, int], blur: float) -> tuple[np.ndarray, np.ndarray]:
    """(g_x, g_y) float32 of ``gray`` inside box = (x0, y0, x1, y1) (exclusive end),
    grey levels per px, after a Gaussian blur of sigma ``blur`` px."""
    x0, y0, x1, y1 = box
    roi = gray[y0:y1, x0:x1].astype(np.float32)
    if blur > 0:
        roi = cv2.GaussianBlur(roi, (0, 0), blur)
    gx = cv2.Sobel(roi, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(roi, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    return gx, gy


def refine_segment(gx: np.ndarray, gy: np.ndarray, segment: np.ndarray, origin=(0.0, 0.0),
                   config: SubpixelConfig | None = None) -> np.ndarray | None:
    """The segment (x1, y1, x2, y2) moved onto the image edge (module doc), or
    None when the edge does not support a refined line. gx, gy: the gradient of
    a box whose top-left pixel is ``origin`` = (x0, y0) in image pixels."""
    cfg = config or SubpixelConfig()
    seg = np.asarray(segment, float).ravel()
    a, b = seg[:2], seg[2:4]
    length = float(np.hypot(*(b - a)))
    if not np.isfinite(length) or length < 2 * cfg.end_margin + cfg.min_samples * cfg.step:
        return None
    d = (b - a) / length
    n = np.array([-d[1], d[0]])
    s = np.arange(cfg.end_margin, length - cfg.end_margin + 1e-9, cfg.step)
    t = np.arange(-cfg.search, cfg.search + 1e-9, 0.5)
    Q = a + s[:, None, None] * d + t[None, :, None] * n - np.asarray(origin, float)   # (S, T, 2) box px
    mx, my = Q[..., 0].astype(np.float32), Q[..., 1].astype(np.float32)
    g = (cv2.remap(gx, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0) * n[0]
         + cv2.remap(gy, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0) * n[1])
    strongest = g[np.arange(len(s)), np.argmax(np.abs(g), axis=1)]
    g = g * (1.0 if np.sum(np.sign(strongest)) >= 0 else -1.0)       # the edge's polarity, positive
    k = np.argmax(g, axis=1)
    peak = g[np.arange(len(s)), k]
    inside = (k > 0) & (k < len(t) - 1) & (peak > 0)
    if not inside.any():
        return None
    rows = np.flatnonzero(inside & (peak >= cfg.min_strength * np.median(peak[inside])))
    if len(rows) < cfg.min_samples:
        return None
    kk = k[rows]
    gm, g0, gp = g[rows, kk - 1], g[rows, kk], g[rows, kk + 1]
    curv = gm - 2.0 * g0 + gp
    delta = np.where(curv < 0, 0.5 * (gm - gp) / np.where(curv < 0, curv, -1.0), 0.0)   # in samples
    off = t[kk] + 0.5 * np.clip(delta, -0.5, 0.5)
    pts = a + s[rows, None] * d + off[:, None] * n
    line = fit_line_tls(pts)
    for _ in range(2):
        r = np.abs(np.cos(line[1]) * pts[:, 0] + np.sin(line[1]) * pts[:, 1] - line[0])
        keep = r <= cfg.inlier
        if keep.sum() < max(cfg.min_samples, cfg.min_fraction * len(s)):
            return None
        line = fit_line_tls(pts[keep])
    c, sn = np.cos(line[1]), np.sin(line[1])
    nl = np.array([c, sn])

    def onto(p):
        return p - (nl @ p - line[0]) * nl

    return np.concatenate([onto(a), onto(b)])


def refine_segments(image: np.ndarray, segments: np.ndarray, config: SubpixelConfig | None = None) -> np.ndarray:
    """Every finite row of segments (k, 4) refined on the undistorted BGR / grey
    ``image`` (rows the edge does not support are returned as they were)."""
    cfg = config or SubpixelConfig()
    segs = np.asarray(segments, float).reshape(-1, 4).copy()
    ok = np.all(np.isfinite(segs), axis=1)
    if not ok.any():
        return segs
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    gray = cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
    h, w = gray.shape[:2]
    pad = cfg.search + 3.0 * max(cfg.blur, 0.5) + 2.0
    xs, ys = segs[ok][:, 0::2], segs[ok][:, 1::2]
    x0, y0 = max(int(np.floor(xs.min() - pad)), 0), max(int(np.floor(ys.min() - pad)), 0)
    x1, y1 = min(int(np.ceil(xs.max() + pad)) + 1, w), min(int(np.ceil(ys.max() + pad)) + 1, h)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return segs
    gx, gy = edge_gradient(gray, (x0, y0, x1, y1), cfg.blur)
    for i in np.flatnonzero(ok):
        r = refine_segment(gx, gy, segs[i], (x0, y0), cfg)
        if r is not None:
            segs[i] = r
    return segs
