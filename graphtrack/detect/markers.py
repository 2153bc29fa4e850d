"""Painted-marker detection by colour (undistorted image -> undistorted px).

A pixel is a marker pixel when its OpenCV HSV value (H in [0, 180), S, V in
[0, 255]) satisfies hue_low <= H <= hue_high, S >= sat_min and V >= val_min
(default: blue paint, H in [90, 120], S, V >= 40). Marker pixels form blobs by
8-connected components. Blobs with area < min_area px or > max_area_frac of
the image are dropped (the latter keeps a blue-tinted or saturated frame from
becoming one giant "marker"), and so is a blob that is not more saturated
than its surroundings: paint is; a tinted surface (a grey shaft under
coloured light, blue-ish tissue) and the colour fringes that chroma
subsampling (JPEG, H.264) leaves along a dark edge on saturated tissue are
not. A marker seen edge-on near the limb is a thin sliver of paint and is
kept (the painted-disc model predicts its centroid). With S_in the median S
of the blob and S_ring that of the non-mask pixels in a ring of width
r = clip(sqrt(area / pi) / 2, 3, 8) px around it, a blob is kept when

    S_in - S_ring >= contrast_min   and   S_in >= contrast_ratio * S_ring

(an empty ring, at the image border, passes), or when the same holds for the
chroma C = S V / 255: saturation means nothing on a near-black pixel (a black
shaft's JPEG noise reads S 150), whose chroma is small, so paint on a black
shaft passes on chroma where its ring's noisy S would reject it, while a
blue-tinted speckle on the shaft (S 56, V 46: C 10) does not. A blob that fails
this test may be paint merged with a surface the colour window also passes (a
grey shaft under blue light): inside it, the pixels whose chroma stands out from
the blob's median chroma by the same rule are measured again as blobs, their
ring now the rest of the blob. Measured on randomized recordings:
docs/decisions/marker-contrast.md. Each blob's centre is the weighted centroid

    c = sum_p w(p) p / sum_p w(p),   w(p) = S(p) / 255,

over its pixels p = (x, y) (pixel centres). On a blob's anti-aliased rim, S
falls with the paint's coverage of the pixel, so c is sub-pixel. Candidates
are searched on a downscaled copy and measured at full resolution (see
:func:`detect_markers`).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class MarkerConfig:
    """HSV window (OpenCV units) and blob size limits."""

    hue_low: int = 90
    hue_high: int = 120
    sat_min: int = 40
    val_min: int = 40
    min_area: int = 8             #: px
    max_area_frac: float = 0.05   #: of the image area
    max_markers: int = 32         #: keep the largest blobs
    max_side: int = 480           #: candidate search on a copy this size (0: full res)
    margin: int = 10              #: px around a candidate box measured at full res (>= ring + 2)
    max_boxes: int = 12           #: more candidates than this: one full-res pass instead
    contrast_min: float = 40.0    #: S_in - S_ring at least (OpenCV S units, module doc)
    contrast_ratio: float = 1.5   #: S_in / S_ring at least


def _bgr(image: np.ndarray) -> np.ndarray | None:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] < 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 1:
        return None
    return img[:, :, :3]


def _mask(img: np.ndarray, cfg: MarkerConfig) -> tuple[np.ndarray, np.ndarray]:
    hsv = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2HSV)
    mask = cv2.inRange(hsv, (int(cfg.hue_low), int(cfg.sat_min), int(cfg.val_min)),
                       (int(cfg.hue_high), 255, 255))
    return mask, hsv


RING_MIN, RING_MAX = 3, 8    #: px, the saturation ring's width (module doc)


def _saturated(sat: np.ndarray, val: np.ndarray, mask: np.ndarray, labels: np.ndarray, stats: np.ndarray,
               ids: np.ndarray, area: np.ndarray, cfg: MarkerConfig) -> np.ndarray:
    """(len(ids),) bool: the blob is more saturated, or more chromatic, than its ring (module doc)."""
    H, W = mask.shape
    keep = np.ones(len(ids), bool)
    for j, k in enumerate(ids):
        r = int(np.clip(round(0.5 * np.sqrt(area[k] / np.pi)), RING_MIN, RING_MAX))
        x, y, w, h = stats[k, :4]
        x0, y0, x1, y1 = max(0, x - r - 1), max(0, y - r - 1), min(W, x + w + r + 1), min(H, y + h + r + 1)
        blob = (labels[y0:y1, x0:x1] == k).astype(np.uint8)
        ring = (cv2.dilate(blob, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
                > 0) & (mask[y0:y1, x0:x1] == 0)
        if not ring.any():
            continue
        s = sat[y0:y1, x0:x1]
        c = _chroma(s, val[y0:y1, x0:x1])                           # only where a blob is
        keep[j] = (_more(float(np.median(s[blob > 0])), float(np.median(s[ring])), cfg)
                   or _more(float(np.median(c[blob > 0])), float(np.median(c[ring])), cfg))
    return keep


def _more(inside, ring, cfg: MarkerConfig):
    """The blob stands out from its ring (saturation or chroma, OpenCV S units); elementwise
    for arrays (a blob's pixels against its median, :func:`_paint_within`)."""
    return (inside - ring >= cfg.contrast_min) & (inside >= cfg.contrast_ratio * ring)


def _chroma(sat: np.ndarray, val: np.ndarray) -> np.ndarray:
    """Chroma C = S V / 255 (OpenCV S units), float32."""
    return sat.astype(np.float32) * val / 255.0


def _blobs(img: np.ndarray, cfg: MarkerConfig, max_area: float, x0: int = 0, y0: int = 0):
    """Weighted centroids (n, 2) and areas (n,) of the blobs of an image (offset x0, y0)."""
    mask, hsv = _mask(img, cfg)
    return _measure(mask, hsv, cfg, max_area, x0, y0, split=True)


def _measure(mask: np.ndarray, hsv: np.ndarray, cfg: MarkerConfig, max_area: float, x0: int, y0: int,
             split: bool):
    """Centroids and areas of the blobs of ``mask`` that pass the size and ring tests; with
    ``split``, also those of the paint inside a blob that failed its ring test (:func:`_paint_within`)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    nz = cv2.findNonZero(mask)
    if nz is None or n <= 1:
        return np.zeros((0, 2)), np.zeros(0)
    nz = nz.reshape(-1, 2)
    xs, ys = nz[:, 0], nz[:, 1]
    lab = labels[ys, xs]
    w = hsv[ys, xs, 1].astype(float) / 255.0
    area = np.bincount(lab, minlength=n).astype(float)
    sw = np.bincount(lab, weights=w, minlength=n)
    sx = np.bincount(lab, weights=w * xs, minlength=n)
    sy = np.bincount(lab, weights=w * ys, minlength=n)
    good = (area >= cfg.min_area) & (area <= max_area) & (sw > 0)
    good[0] = False  # background
    ids = np.flatnonzero(good)
    ok = _saturated(hsv[:, :, 1], hsv[:, :, 2], mask, labels, stats, ids, area, cfg)
    kept, failed = ids[ok], ids[~ok]
    c, a = np.stack([sx[kept] / sw[kept] + x0, sy[kept] / sw[kept] + y0], 1), area[kept]
    if split and len(failed):
        inner = _paint_within(hsv, labels, stats, failed[area[failed] >= 2 * cfg.min_area], cfg)
        if inner is not None:
            c2, a2 = _measure(inner, hsv, cfg, max_area, x0, y0, split=False)
            c, a = np.concatenate([c, c2]), np.concatenate([a, a2])
    return c, a


def _paint_within(hsv: np.ndarray, labels: np.ndarray, stats: np.ndarray, ids: np.ndarray,
                  cfg: MarkerConfig) -> np.ndarray | None:
    """uint8 mask of the pixels of blobs ``ids`` whose chroma C = S V / 255 stands out from
    their blob's median chroma C_b as a blob from its ring (C - C_b >= contrast_min and
    C >= contrast_ratio C_b): paint merged with a tinted surface that passes the colour
    window too (a grey shaft under blue light), found again inside it. None: no blob."""
    if not len(ids):
        return None
    out = np.zeros(labels.shape, np.uint8)
    for k in ids:
        x, y, w, h = stats[k, :4]                   # the blob's bounding box
        ys, xs = np.nonzero(labels[y:y + h, x:x + w] == k)
        ys, xs = ys + y, xs + x
        C = _chroma(hsv[ys, xs, 1], hsv[ys, xs, 2])
        keep = _more(C, float(np.median(C)), cfg)
        out[ys[keep], xs[keep]] = 255
    return out


def _candidate_boxes(mask: np.ndarray) -> np.ndarray:
    """(n, 5) int: x, y, w, h and mask-pixel count of each outer contour's bounding box.

    The candidate search only needs boxes: outer contours find them ~30x faster
    than connectedComponentsWithStats on a sparse mask (0.03 vs 1.0 ms at
    270 x 480). The count is of all mask pixels in the box (a loose pre-filter;
    every blob is measured exactly at full resolution)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = np.zeros((len(contours), 5), int)
    for i, c in enumerate(contours):
        x, y, bw, bh = cv2.boundingRect(c)
        out[i] = x, y, bw, bh, cv2.countNonZero(mask[y:y + bh, x:x + bw])
    return out


def detect_markers(image: np.ndarray, config: MarkerConfig | None = None) -> np.ndarray:
    """Marker centroids (M, 2) float (x, y) in the image's (undistorted) pixels,
    largest blob first. Non-colour or non-uint8 images give (0, 2).

    For speed, candidate blobs are found on a copy downscaled to ``max_side``
    (INTER_AREA); each is then measured at full resolution in its bounding box
    (grown by ``margin`` px), so the centroids are full-resolution ones.
    """
    cfg = config or MarkerConfig()
    img = _bgr(image)
    if img is None:
        return np.zeros((0, 2))
    H, W = img.shape[:2]
    max_area = cfg.max_area_frac * H * W
    s = min(1.0, cfg.max_side / max(H, W)) if cfg.max_side else 1.0
    w, h = int(round(W * s)), int(round(H * s))
    if s >= 1.0 or min(w, h) < 8:
        c, a = _blobs(img, cfg, max_area)
    else:
        small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        mask, _ = _mask(small, cfg)
        if cv2.countNonZero(mask) == 0:
            return np.zeros((0, 2))
        stats = _candidate_boxes(mask)
        sx, sy = W / w, H / h
        area = stats[:, 4] * sx * sy
        boxes = stats[(area >= 0.25 * cfg.min_area) & (area <= 1.5 * max_area)]
        cs, as_ = [], []
        if len(boxes) > cfg.max_boxes:  # many candidates: one full-resolution pass is cheaper
            c, a = _blobs(img, cfg, max_area)
            cs, as_ = [c], [a]
            boxes = boxes[:0]
        for bx, by, bw, bh, _ in boxes:
            x0 = max(0, int(np.floor(bx * sx)) - cfg.margin)
            y0 = max(0, int(np.floor(by * sy)) - cfg.margin)
            x1 = min(W, int(np.ceil((bx + bw) * sx)) + cfg.margin)
            y1 = min(H, int(np.ceil((by + bh) * sy)) + cfg.margin)
            c, a = _blobs(img[y0:y1, x0:x1], cfg, max_area, x0, y0)
            # keep blobs centred in this box's core (a neighbour's box may overlap)
            core = ((c[:, 0] >= bx * sx - 1.0) & (c[:, 0] <= (bx + bw) * sx)
                    & (c[:, 1] >= by * sy - 1.0) & (c[:, 1] <= (by + bh) * sy))
            cs.append(c[core])
            as_.append(a[core])
        if not cs:
            return np.zeros((0, 2))
        c, a = np.concatenate(cs), np.concatenate(as_)
        if len(c) > 1:  # overlapping boxes may report one blob twice
            d = np.hypot(c[:, None, 0] - c[None, :, 0], c[:, None, 1] - c[None, :, 1])
            dup = np.triu(d < 1.0, 1).any(0)
            c, a = c[~dup], a[~dup]
    order = np.argsort(-a, kind="stable")[: cfg.max_markers]
    return c[order]
