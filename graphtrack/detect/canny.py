"""The method's classical baseline: Canny edges + Hough lines -> shaft edges.

Pipeline on an undistorted BGR frame (all returned coordinates are full-
resolution undistorted pixels):

1. grey, downscaled by s = min(1, max_side / max(H, W)) (INTER_AREA; 0.5 for a
   540x960 frame with the default max_side = 480); a low-resolution pixel
   (u, v) is the full-resolution point ((u + 1/2)/s - 1/2, (v + 1/2)/s - 1/2).
2. Gaussian blur, 3x3 Sobel gradients g = (g_x, g_y), Canny (hysteresis
   thresholds low / high on |g|_2). Edges touching pure-black pixels (the empty
   border an undistortion leaves) are dropped.
3. Hough lines (:mod:`graphtrack.detect.hough`) with the method's
   hyper-parameters: rho resolution 5 px, theta resolution 0.09 rad, vote
   threshold 100 edge pixels (full-resolution units), votes filtered by the
   gradient angle phi = atan2(g_y, g_x) mod pi (``hough_orientation_tol``,
   None: the plain transform); the ``max_lines`` strongest peaks go on
   (``cluster_peaks`` also clusters the raw peaks).
4. Refit and candidate segment of each line
   (:mod:`graphtrack.detect.line_refit`: fine local Hough, then total least
   squares in bands of 2 band and band px, band = max(refine_band, 1/s); the
   longest run of inliers split at gaps > max_gap px). Segments shorter than
   min_length px are dropped; the survivors are clustered (the method's
   near-duplicates: within 5 px, measured at the weaker segment's midpoint,
   and 0.09 rad of a longer one).
5. Association with the shaft's two edges (:mod:`graphtrack.detect.association`,
   gated by ``predicted_lines`` when given) and colour markers
   (:mod:`graphtrack.detect.markers`).

The heatmap H is a LINE heatmap, the analogue of SOLD2's: the Canny edge
pixels (nearest-neighbour upscaled to full resolution, ~1/s px thick) within
``line_band`` px of a candidate segment, as float32 0/1; edges that support no
line are not line pixels. Why each of these departs from the plain method, with
measurements: docs/decisions/canny-detector-changes.md.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np

from graphtrack.detect.association import AssociationConfig, associate
from graphtrack.detect.base import Detection, detector_image
from graphtrack.detect.hough import hough_lines, suppress
from graphtrack.detect.line_refit import refit_lines
from graphtrack.detect.markers import MarkerConfig, detect_markers
from graphtrack.geometry.image_scale import scale_points
from graphtrack.geometry.lines import line_difference


@dataclass
class CannyConfig:
    """Hyper-parameters (full-resolution px, rad, counts)."""

    low_threshold: float = 50.0     #: Canny hysteresis, on the 3x3 Sobel |g|_2
    high_threshold: float = 150.0
    blur_ksize: int = 5             #: Gaussian blur before Canny (0: none)
    rho_res: float = 5.0            #: Hough rho resolution (px)
    theta_res: float = 0.09         #: Hough theta resolution (rad)
    votes: int = 100                #: Hough vote threshold (edge pixels)
    cluster_rho: float = 5.0        #: near-duplicate lines (px)
    cluster_theta: float = 0.09     #: near-duplicate lines (rad)
    max_hough: int = 300            #: Hough peaks considered
    max_lines: int = 60             #: strongest peaks refined
    cluster_peaks: bool = False     #: also cluster the raw peaks (before refinement)
    refine: bool = True             #: TLS refit of each Hough line
    refine_band: float = 1.5        #: px, final inlier band (>= 1/s)
    orientation_tol: float = 0.35   #: rad, refit pixels' gradient vs normal; None: off
    fine_theta: float = 0.1         #: rad, half-range of the fine local Hough
    hough_orientation_tol: float | None = 0.2  #: rad, oriented voting; None: plain Hough
    max_gap: float = 30.0           #: px, gap splitting a line's edge pixels
    min_length: float = 40.0        #: px, shortest candidate segment
    line_band: float = 2.5          #: px, heatmap keeps edge pixels this close to a segment
    max_side: int = 480             #: downscale so the long side is <= this
    scale: float | None = None      #: explicit downscale factor (overrides max_side)
    black_level: int = 2            #: grey <= this is empty border; < 0: off
    detect_markers: bool = True
    markers: MarkerConfig = field(default_factory=MarkerConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)


def _gray(img: np.ndarray) -> np.ndarray:
    """(H, W) grey of a :func:`~graphtrack.detect.base.detector_image`."""
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)


class CannyDetector:
    """Canny + Hough shaft-edge detector (see the module doc).

    ``CannyDetector(config, **overrides)``: overrides replace CannyConfig
    fields (e.g. ``CannyDetector(votes=80, scale=1.0)``).
    """

    name = "canny"

    def __init__(self, config: CannyConfig | None = None, **overrides):
        cfg = config or CannyConfig()
        unknown = [k for k in overrides if k not in {f.name for f in fields(CannyConfig)}]
        if unknown:
            raise TypeError(f"CannyDetector: unknown option(s) {', '.join(unknown)}")
        self.config = replace(cfg, **overrides)

    @property
    def association(self) -> AssociationConfig:
        """The configured association gates (as on the other detectors)."""
        return self.config.association

    # -- stages -------------------------------------------------------------------
    def edges(self, gray: np.ndarray, s: float):
        """Canny edge map and Sobel gradients of the (downscaled) grey image."""
        cfg = self.config
        g = gray
        if cfg.blur_ksize and cfg.blur_ksize > 1:
            k = int(cfg.blur_ksize) | 1
            g = cv2.GaussianBlur(g, (k, k), 0)
        dx = cv2.Sobel(g, cv2.CV_16S, 1, 0, ksize=3)
        dy = cv2.Sobel(g, cv2.CV_16S, 0, 1, ksize=3)
        edges = cv2.Canny(dx, dy, float(cfg.low_threshold), float(cfg.high_threshold), L2gradient=True)
        if cfg.black_level >= 0:
            dark = (gray <= cfg.black_level).astype(np.uint8)
            if dark.any():
                dark = cv2.dilate(dark, np.ones((5, 5), np.uint8))
                edges[dark > 0] = 0
        return edges, dx, dy

    def hough(self, edges: np.ndarray, s: float, shape, xs=None, ys=None,
              phi=None) -> np.ndarray:
        """Hough lines (N, 2) full-resolution (rho, theta), strongest first
        (:func:`graphtrack.detect.hough.hough_lines` with this configuration)."""
        cfg = self.config
        return hough_lines(edges, s, shape, rho_res=cfg.rho_res, theta_res=cfg.theta_res, votes=cfg.votes,
                           orientation_tol=cfg.hough_orientation_tol, max_hough=cfg.max_hough,
                           max_lines=cfg.max_lines,
                           cluster=(cfg.cluster_rho, cfg.cluster_theta) if cfg.cluster_peaks else None,
                           xs=xs, ys=ys, phi=phi)

    def fit(self, lines: np.ndarray, X: np.ndarray, phi: np.ndarray, s: float):
        """Refits, candidate segments (N, 4) and support (N,) of Hough lines (N, 2)
        (:func:`graphtrack.detect.line_refit.refit_lines` with this configuration)."""
        cfg = self.config
        return refit_lines(lines, X, phi, s, orientation_tol=cfg.orientation_tol, refine=cfg.refine,
                           refine_band=cfg.refine_band, fine_theta=cfg.fine_theta, rho_res=cfg.rho_res,
                           max_gap=cfg.max_gap)

    def candidates(self, lines: np.ndarray, X: np.ndarray, phi: np.ndarray, s: float):
        """Candidate lines (M, 2) and segments (M, 4), longest first: the refitted Hough
        lines with a segment of at least ``min_length`` px, near-duplicates (within
        ``cluster_rho`` px of a longer one at their midpoint, ``cluster_theta`` rad)
        suppressed."""
        cfg = self.config
        lines, segs, _ = self.fit(lines, X, phi, s)
        length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
        good = np.isfinite(length) & (length >= cfg.min_length)
        lines, segs, length = lines[good], segs[good], length[good]
        order = np.argsort(-length, kind="stable")
        lines, segs = lines[order], segs[order]
        if len(lines) > 1:
            mid = 0.5 * (segs[:, :2] + segs[:, 2:])
            c, sn = np.cos(lines[:, 1]), np.sin(lines[:, 1])
            off = np.abs(c[:, None] * mid[None, :, 0] + sn[:, None] * mid[None, :, 1]
                         - lines[:, None, 0])            # [i, j]: midpoint j to line i
            _, dth = line_difference(lines[:, None, 0], lines[:, None, 1],
                                     lines[None, :, 0], lines[None, :, 1])
            near = (off <= cfg.cluster_rho) & (np.abs(dth) <= cfg.cluster_theta)
            keep = suppress(near, cfg.max_lines)
            lines, segs = lines[keep], segs[keep]
        return lines, segs

    def _near_segments(self, segs: np.ndarray, shape) -> np.ndarray:
        """(H, W) uint8 mask, 255 within ``line_band`` px of a segment (the heatmap's support)."""
        near_line = np.zeros(shape, np.uint8)
        thick = max(1, int(round(2 * self.config.line_band + 1)))
        for x1, y1, x2, y2 in np.round(segs * 16).astype(np.int64):
            cv2.line(near_line, (int(x1), int(y1)), (int(x2), int(y2)), 1, thick, cv2.LINE_8, shift=4)
        return near_line * 255

    # -- the detector ---------------------------------------------------------------
    def detect(self, image: np.ndarray, predicted_lines: np.ndarray | None = None,
               association: AssociationConfig | None = None) -> Detection:
        """Detect on an undistorted BGR (or grey) uint8 frame; ``predicted_lines``
        (2, 2) gate the association; ``association`` overrides the configured
        gates for this call (e.g. widened after a tracking loss)."""
        t_start = time.perf_counter()
        cfg = self.config
        image = detector_image(image)
        gray = _gray(image)
        H, W = gray.shape
        det = Detection()
        if cfg.detect_markers and min(H, W) > 0:
            det.markers = detect_markers(image, cfg.markers)
        s = cfg.scale if cfg.scale is not None else min(1.0, cfg.max_side / max(H, W, 1))
        s = float(min(max(s, 1e-3), 1.0))
        w, h = max(1, int(round(W * s))), max(1, int(round(H * s)))
        if min(h, w) < 8:
            det.heatmap = np.zeros((H, W), np.float32)
            det.ms = 1e3 * (time.perf_counter() - t_start)
            return det
        s_x, s_y = w / W, h / H
        s = 0.5 * (s_x + s_y)
        small = cv2.resize(gray, (w, h), interpolation=cv2.INTER_AREA) if (w, h) != (W, H) else gray
        edges, dx, dy = self.edges(small, s)
        big = cv2.resize(edges, (W, H), interpolation=cv2.INTER_NEAREST) if (w, h) != (W, H) else edges

        nz = cv2.findNonZero(edges)
        lines = np.zeros((0, 2))
        if nz is not None:
            nz = nz.reshape(-1, 2)
            xs, ys = nz[:, 0], nz[:, 1]
            phi = np.mod(np.arctan2(dy[ys, xs].astype(float), dx[ys, xs].astype(float)), np.pi)
            lines = self.hough(edges, s, (H, W), xs, ys, phi)
        if len(lines):
            X = scale_points(np.stack([xs, ys], 1), 1.0 / s_x, 1.0 / s_y)
            lines, segs = self.candidates(lines, X, phi, s)
            det.segments = segs
            big = big & self._near_segments(segs, (H, W))
            a = associate(lines, segs, predicted_lines, association or cfg.association)
            det.shaft_lines, det.shaft_segments, det.edge_ids = a.lines, a.segments, a.edge_ids
        if len(lines) == 0:
            big = np.zeros_like(big)
        det.heatmap = (big > 0).astype(np.float32)
        det.ms = 1e3 * (time.perf_counter() - t_start)
        return det
