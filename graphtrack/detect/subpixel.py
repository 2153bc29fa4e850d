"""Sub-pixel refinement of a detected shaft edge on the full-resolution image.

Each associated segment of the learned detector (found on a 1/4-scale
heatmap, good to a pixel or two) is moved onto the image's edge:

1. the grey image (Gaussian blur ``blur`` px, 3x3 Sobel / 8: grey levels per
   px) gives the gradient g, only in the segments' bounding box;
2. along the segment a = e^a, b = e^b (direction d, normal n), every ``step``
   px from ``end_margin`` px inside each end (the end face's corner and the
   image border are not edge), the signed normal gradient g(p + t n) . n is
   sampled (bilinear) for t in [-search, search] every 0.5 px;
3. the edge's polarity (dark shaft on a lighter background or the reverse) is
   the majority sign of the rows' strongest samples (the shaft's two edges,
   their normals pointing into the shaft, share one, voted by both); each
   row's peak of the gradient of that polarity, if inside the window and at
   least ``min_strength`` of the rows' median peak (which must reach
   ``min_gradient`` grey levels per px), is located to sub-pixel by the vertex
   of a least-squares parabola through the 5 samples around it;
4. a total-least-squares line through the peaks, refitted on those within
   ``inlier`` px of it, is the refined edge when it keeps at least
   ``min_fraction`` of the rows (and ``min_samples``); the refined segment is
   e^a, e^b projected on it;
5. when steps 3-4 find no line and most rows' peak sits on the window's inner end
   (the net's band lies outside the silhouette, on a blurred or low-contrast edge
   by more than ``search``), they run once more over t in [-search, search +
   ``reach``], into the shaft only: outwards lies the background, whose edges can
   merge with the silhouette's (below). Otherwise the segment is kept as detected.

A second edge inside the window (the black border an undistortion leaves, a
stripe, a tissue fold) makes a row ambiguous, and an edge with many such rows
is kept as detected (:func:`fit_edge`). Parallel edges closer than the
camera's and the gradient's blur merge into one peak and the refined line
follows the stronger: a known limit of any gradient-peak locator.

Coordinates are undistorted full-resolution pixels (pixel centres at
integers, as everywhere in graphtrack). The image is the undistorted one, or
the raw one with its camera: the samples are then read through the
distortion (:func:`edge_profiles`). Decision and measurements:
docs/decisions/subpixel-edges.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from graphtrack.detect.ransac import fit_line_tls


@dataclass
class SubpixelConfig:
    """Refinement settings (px of the full-resolution image, fractions)."""

    search: float = 3.0        #: px either side of the detected segment
    reach: float = 6.0         #: px further into the shaft searched when its edge lies beyond the window
    step: float = 4.0          #: px between samples along it
    end_margin: float = 6.0    #: px left out at each end
    blur: float = 1.0          #: Gaussian sigma before the gradient
    min_strength: float = 0.3  #: a row's peak vs the median peak
    min_gradient: float = 2.0  #: grey levels / px: the rows' median peak must reach it
    inlier: float = 1.0        #: px, TLS inlier band
    min_fraction: float = 0.5  #: rows that must support the refined line
    min_samples: int = 8
    rival: float = 0.3         #: a second |gradient| peak this strong (vs the row's) ...
    rival_gap: float = 1.5     #: ... this far (px) from it makes the row ambiguous
    max_ambiguous: float = 0.2  #: fraction of ambiguous rows that rejects the edge


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


@dataclass
class EdgeProfiles:
    """The signed normal gradient across the segment a -> b: g[i, j] =
    grad(p_i + t_j n) . n at p_i = a + s_i d (grey levels / px), n pointing
    ``toward`` the shaft when given."""

    a: np.ndarray
    b: np.ndarray
    d: np.ndarray
    n: np.ndarray
    s: np.ndarray
    t: np.ndarray
    g: np.ndarray

    def polarity_votes(self) -> float:
        """Sum over rows of the sign of each row's strongest sample."""
        strongest = self.g[np.arange(len(self.s)), np.argmax(np.abs(self.g), axis=1)]
        return float(np.sum(np.sign(strongest)))

    def peaks(self, polarity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(g with the polarity's sign, each row's peak sample index k, its value) for
        ``polarity`` (+1: the gradient points along n)."""
        g = self.g * (1.0 if polarity >= 0 else -1.0)
        k = np.argmax(g, axis=1)
        return g, k, g[np.arange(len(k)), k]


def edge_profiles(gx: np.ndarray, gy: np.ndarray, segment: np.ndarray, origin=(0.0, 0.0),
                  config: SubpixelConfig | None = None, toward=None, camera=None,
                  centre: float = 0.0) -> EdgeProfiles | None:
    """Sample the normal gradient across ``segment`` (module doc, step 2); None
    for a segment too short for ``min_samples`` rows. gx, gy: the gradient of a
    box whose top-left pixel is ``origin`` = (x0, y0) in image pixels; toward: a
    point on the normal's side (the other edge of the shaft), or None; centre: px
    along n of the window's centre (t in centre +- search).

    camera: gx, gy are the gradient of that camera's RAW image while the segment is in
    undistorted pixels. Each sample p is then read at its raw pixel r(p) =
    camera.distort_pixels(p), and the undistorted image's derivative along n is the
    chain rule's grad_raw(r(p)) . (J n), J = dr/dp, J n by central difference over
    1 px: the image is never undistorted."""
    cfg = config or SubpixelConfig()
    seg = np.asarray(segment, float).ravel()
    a, b = seg[:2], seg[2:4]
    length = float(np.hypot(*(b - a)))
    if not np.isfinite(length) or length < 2 * cfg.end_margin + cfg.min_samples * cfg.step:
        return None
    d = (b - a) / length
    n = np.array([-d[1], d[0]])
    if toward is not None and n @ (np.asarray(toward, float) - a) < 0:
        n = -n
    s = np.arange(cfg.end_margin, length - cfg.end_margin + 1e-9, cfg.step)
    t = centre + np.arange(-cfg.search, cfg.search + 1e-9, 0.5)
    Q = a + s[:, None, None] * d + t[None, :, None] * n                  # (S, T, 2) image px
    dn = np.broadcast_to(n, Q.shape)
    if camera is not None:
        R = camera.distort_pixels(np.stack([Q, Q + 0.5 * n, Q - 0.5 * n]))   # one call: it is per edge
        Q, dn = R[0], R[1] - R[2]
    Q = Q - np.asarray(origin, float)                                        # box px
    mx, my = Q[..., 0].astype(np.float32), Q[..., 1].astype(np.float32)
    g = (cv2.remap(gx, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0) * dn[..., 0]
         + cv2.remap(gy, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0) * dn[..., 1])
    return EdgeProfiles(a, b, d, n, s, t, g)


def fit_edge(p: EdgeProfiles, polarity: float, config: SubpixelConfig | None = None) -> np.ndarray | None:
    """Steps 3-4 of the module doc for the given polarity (+1: the gradient
    points along p.n): the refined segment, or None. A row is ambiguous when a
    second local peak of |g|, of either polarity, of at least ``rival`` times
    its peak lies ``rival_gap`` px or more from it (a black undistortion
    border, a stripe or a second step inside the window: which of them is the
    silhouette the gradient cannot tell); more than ``max_ambiguous`` of such
    rows reject the edge, which then stays as detected.
    The peak is the vertex of a least-squares parabola through the 5 samples
    around the row's maximum (3 samples leave a bias of up to 0.13 px that
    depends on where the edge falls in the pixel grid)."""
    cfg = config or SubpixelConfig()
    g, k, peak = p.peaks(polarity)
    S, T = g.shape
    inside = (k >= 2) & (k <= T - 3) & (peak > 0)
    if inside.sum() < cfg.min_samples:
        return None
    median_peak = float(np.median(peak[inside]))
    if median_peak < cfg.min_gradient:
        return None
    rows = np.flatnonzero(inside & (peak >= cfg.min_strength * median_peak))
    if len(rows) < cfg.min_samples:
        return None
    G = g[rows]
    A = np.abs(G)                       # a rival may have either polarity
    local = np.zeros_like(A, dtype=bool)
    local[:, 1:-1] = (A[:, 1:-1] >= A[:, :-2]) & (A[:, 1:-1] >= A[:, 2:])
    far = np.abs(np.arange(T)[None, :] - k[rows, None]) * 0.5 >= cfg.rival_gap
    rival = np.any(local & far & (A >= cfg.rival * peak[rows, None]), axis=1)
    if rival.mean() > cfg.max_ambiguous:
        return None
    kk = k[rows]
    w = G[np.arange(len(rows))[:, None], kk[:, None] + np.arange(-2, 3)[None, :]]     # (R, 5)
    curv = (2 * w[:, 0] - w[:, 1] - 2 * w[:, 2] - w[:, 3] + 2 * w[:, 4]) / 14.0     # x^2 coefficient
    slope = (-2 * w[:, 0] - w[:, 1] + w[:, 3] + 2 * w[:, 4]) / 10.0                  # x coefficient
    delta = np.where(curv < 0, -slope / (2.0 * np.where(curv < 0, curv, -1.0)), 0.0)  # in samples
    off = p.t[kk] + 0.5 * np.clip(delta, -1.0, 1.0)
    pts = p.a + p.s[rows, None] * p.d + off[:, None] * p.n
    line = fit_line_tls(pts)
    for _ in range(2):
        r = np.abs(math.cos(line[1]) * pts[:, 0] + math.sin(line[1]) * pts[:, 1] - line[0])
        keep = r <= cfg.inlier
        if keep.sum() < max(cfg.min_samples, cfg.min_fraction * S):
            return None
        line = fit_line_tls(pts[keep])
    nl = np.array([np.cos(line[1]), np.sin(line[1])])
    a, b = p.a, p.b
    return np.concatenate([a - (nl @ a - line[0]) * nl, b - (nl @ b - line[0]) * nl])


def refine_segment(gx: np.ndarray, gy: np.ndarray, segment: np.ndarray, origin=(0.0, 0.0),
                   config: SubpixelConfig | None = None, polarity: float | None = None,
                   toward=None) -> np.ndarray | None:
    """The segment (x1, y1, x2, y2) moved onto the image edge (module doc), or
    None when the edge does not support a refined line. polarity: the sign of
    the gradient along the normal (pointing ``toward``, when given); None: the
    majority of the segment's own rows."""
    p = edge_profiles(gx, gy, segment, origin, config, toward)
    if p is None:
        return None
    return fit_edge(p, p.polarity_votes() if polarity is None else polarity, config)


def _box_points(segs: np.ndarray, camera) -> np.ndarray:
    """Points (n, 2) whose bounding box, padded, holds every sample of the segments
    (k, 4): their ends, or with ``camera`` 17 points along each taken to raw pixels."""
    if camera is None:
        return segs.reshape(-1, 2)
    f = np.linspace(0.0, 1.0, 17)[None, :, None]
    return camera.distort_pixels(segs[:, None, :2] + f * (segs[:, None, 2:] - segs[:, None, :2])).reshape(-1, 2)


def refine_segments(image: np.ndarray, segments: np.ndarray, config: SubpixelConfig | None = None,
                    camera=None) -> np.ndarray:
    """Every finite row of segments (k, 4) refined on the undistorted BGR / grey
    ``image`` (rows the edge does not support are returned as they were). camera:
    ``image`` is that camera's RAW frame, the segments and the result are in its
    undistorted pixels (sampled through the distortion, :func:`edge_profiles`)."""
    cfg = config or SubpixelConfig()
    segs = np.asarray(segments, float).reshape(-1, 4).copy()
    ok = np.all(np.isfinite(segs), axis=1)
    if not ok.any():
        return segs
    img = np.asarray(image)
    h, w = img.shape[:2]
    pad = cfg.search + cfg.reach + 3.0 * max(cfg.blur, 0.5) + 2.0
    if camera is not None:
        pad *= 1.5                   # the distortion stretches the +-search window locally
    pts = _box_points(segs[ok], camera)
    xs, ys = pts[:, 0], pts[:, 1]
    x0, y0 = max(int(np.floor(xs.min() - pad)), 0), max(int(np.floor(ys.min() - pad)), 0)
    x1, y1 = min(int(np.ceil(xs.max() + pad)) + 1, w), min(int(np.ceil(ys.max() + pad)) + 1, h)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return segs
    img = img[y0:y1, x0:x1]          # grey levels are per pixel: convert only the box
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    gray = cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
    gx, gy = edge_gradient(gray, (0, 0, x1 - x0, y1 - y0), cfg.blur)
    idx = np.flatnonzero(ok)
    mid = (segs[:, :2] + segs[:, 2:]) / 2
    # the shaft's two edges: normals point into the shaft (toward the other edge's
    # midpoint), and one polarity, voted by both, serves both edges
    toward = {int(i): mid[int(idx[1 - j])] for j, i in enumerate(idx)} if len(idx) == 2 else {}
    prof = {int(i): edge_profiles(gx, gy, segs[i], (x0, y0), cfg, toward.get(int(i)), camera) for i in idx}
    joint = None
    if len(toward) == 2 and all(p is not None for p in prof.values()):
        joint = 1.0 if sum(p.polarity_votes() for p in prof.values()) >= 0 else -1.0
    for i, p in prof.items():
        if p is None:
            continue
        polarity = p.polarity_votes() if joint is None else joint
        r = fit_edge(p, polarity, cfg)
        if r is None and i in toward and _beyond_inner_end(p, polarity, cfg):
            r = _search_inward(gx, gy, segs[i], (x0, y0), cfg, polarity, toward[i], camera)
        if r is not None:
            segs[i] = r
    return segs


def _beyond_inner_end(p: EdgeProfiles, polarity: float, config: SubpixelConfig) -> bool:
    """Most rows' peak of the given polarity sits on the window's last two samples
    along p.n (into the shaft): the edge lies beyond the window, further into the shaft."""
    g, k, peak = p.peaks(polarity)
    strong = peak > 0
    return bool(strong.sum() >= config.min_samples and np.mean(k[strong] >= g.shape[1] - 2) >= 0.5)


def _search_inward(gx, gy, segment: np.ndarray, origin, config: SubpixelConfig, polarity: float,
                   toward, camera) -> np.ndarray | None:
    """Steps 2-4 once more over t in [-search, search + reach] (into the shaft): the
    refined segment (the detected ends projected on the refined line), or None."""
    wide = replace(config, search=config.search + 0.5 * config.reach)
    p = edge_profiles(gx, gy, segment, origin, wide, toward, camera, centre=0.5 * config.reach)
    return None if p is None else fit_edge(p, polarity, wide)
