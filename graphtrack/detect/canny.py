"""The method's classical baseline: Canny edges + Hough lines -> shaft edges.

Pipeline on an undistorted BGR frame (all returned coordinates are full-
resolution undistorted pixels):

1. grey, downscaled by s = min(1, max_side / max(H, W)) (INTER_AREA; 0.5 for a
   540x960 frame with the default max_side = 480) to keep the detector at a few
   ms per frame; a low-resolution pixel (u, v) is the full-resolution point
   ((u + 1/2)/s - 1/2, (v + 1/2)/s - 1/2).
2. Gaussian blur, 3x3 Sobel gradients g = (g_x, g_y), Canny (hysteresis
   thresholds low / high on |g|_2). Edges touching pure-black pixels (the empty
   border an undistortion leaves) are dropped.
3. Hough accumulator with the method's hyper-parameters: rho resolution 5 px,
   theta resolution 0.09 rad, vote threshold 100 edge pixels (all in full-
   resolution units: the low-resolution transform uses 5 s px and 100 s votes).
   Oriented voting (``hough_orientation_tol``, default 0.2 rad; None gives the
   plain transform): theta is cut into sectors of 5 bins and an edge pixel with
   gradient angle phi = atan2(g_y, g_x) mod pi votes only in the sectors that
   come within the tolerance of phi (a line's normal is its pixels' gradient
   direction). This keeps textured tissue from reaching 100 random votes. The
   ``max_lines`` strongest peaks go on to refinement. (The method's clustering
   of near-duplicates at 5 px / 0.09 rad is applied to the refined lines, in
   step 5: on raw peaks it merges a shaft edge with a specular streak 10 px
   inside it, whose peaks are neighbouring bins; ``cluster_peaks`` restores it
   there, with rho measured from the image centre.)
4. Refinement (``refine``; see :meth:`CannyDetector.fit`): the Hough bins are
   5 px / 0.09 rad wide, so each line is re-estimated from the edge pixels
   whose gradient direction is within ``orientation_tol`` of its normal: a
   fine local Hough (0.01 rad, 1 px, +-fine_theta) around the peak, then total
   least squares on the pixels with |R(p | theta, rho)| <= 2 band, then
   <= band (band = max(refine_band, 1/s) px).
5. Candidate segment of each line: its final inlier pixels, projected on the
   line direction (-sin theta, cos theta), split at gaps > max_gap px; the
   longest run gives the endpoints (x1, y1, x2, y2). Runs shorter than
   min_length px are dropped; the survivors are clustered (the method's
   near-duplicates: within 5 px, measured at the weaker segment's midpoint,
   and 0.09 rad of a longer one).
6. Association with the shaft's two edges (:mod:`graphtrack.detect.association`,
   gated by ``predicted_lines`` when given) and colour markers
   (:mod:`graphtrack.detect.markers`).

The heatmap H is a LINE heatmap, the analogue of SOLD2's: the Canny edge
pixels (brought back to full resolution by nearest-neighbour upscaling, so an
edge is ~1/s px thick there) that lie within ``line_band`` px of a candidate
segment, as float32 0/1. Edges that support no line -- the specular stripe
along a lit shaft, marker blobs, tissue texture -- are not line pixels; with
the raw edge map they entered the pixel sets E_e/E_l (alpha = 10 px) and, as a
parallel stripe a few px inside the silhouette, pulled the estimated edge
inwards, making the shaft look narrower and so farther away (the smoother on
a structured recording converged 10 mm off with them).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np

from graphtrack.detect.association import AssociationConfig, associate
from graphtrack.detect.base import Detection
from graphtrack.detect.markers import MarkerConfig, detect_markers
from graphtrack.detect.ransac import tls_from_moments
from graphtrack.geometry.lines import canonical, line_difference


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


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"detector expects a uint8 image, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        return cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), cv2.COLOR_BGR2GRAY)
    raise ValueError(f"detector expects an (H, W) or (H, W, 3) image, got shape {img.shape}")


def _nms(near: np.ndarray, limit: int) -> list[int]:
    """Greedy suppression over rows sorted strongest first; near: (N, N) bool."""
    suppressed = np.zeros(len(near), dtype=bool)
    keep: list[int] = []
    for i in range(len(near)):
        if suppressed[i]:
            continue
        keep.append(i)
        if len(keep) >= limit:
            break
        suppressed |= near[i]
    return keep


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
        """Clustered Hough lines (N, 2) full-resolution (rho, theta), strongest first.

        With ``hough_orientation_tol`` set and the edge pixels' gradient angles
        phi (mod pi) given, theta is split into sectors of 5 bins and an edge
        pixel votes only in the sectors within the tolerance of its phi.
        """
        cfg = self.config
        thr = max(1, int(round(cfg.votes * s)))
        rres, tres = cfg.rho_res * s, cfg.theta_res
        found = []
        if phi is None or cfg.hough_orientation_tol is None:
            out = cv2.HoughLinesWithAccumulator(edges, rres, tres, thr)
            if out is not None:
                found.append(out.reshape(-1, 3))
        else:
            tol = float(cfg.hough_orientation_tol)
            width = 5 * tres
            for k in range(int(np.ceil(np.pi / width))):
                lo, hi = k * width, min((k + 1) * width, np.pi)
                centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + tol
                d = np.abs(np.mod(phi - centre + 0.5 * np.pi, np.pi) - 0.5 * np.pi)
                m = d <= half
                if m.sum() < thr:
                    continue
                img = np.zeros_like(edges)
                img[ys[m], xs[m]] = 255
                out = cv2.HoughLinesWithAccumulator(img, rres, tres, thr, min_theta=lo, max_theta=hi)
                if out is not None:
                    found.append(out.reshape(-1, 3))
        if not found:
            return np.zeros((0, 2))
        hl = np.concatenate(found).astype(float)
        hl = hl[np.argsort(-hl[:, 2], kind="stable")][: cfg.max_hough]
        c, sn = np.cos(hl[:, 1]), np.sin(hl[:, 1])
        rho = (hl[:, 0] - (0.5 * s - 0.5) * (c + sn)) / s
        rho, theta = canonical(rho, hl[:, 1])
        if cfg.cluster_peaks:
            H, W = shape
            rc = rho - (np.cos(theta) * (W - 1) / 2 + np.sin(theta) * (H - 1) / 2)
            drho, dth = line_difference(rc[:, None], theta[:, None], rc[None], theta[None])
            near = (np.abs(drho) <= cfg.cluster_rho) & (np.abs(dth) <= cfg.cluster_theta + 1e-9)
        else:  # only exact duplicates (a bin shared by two sectors)
            near = (np.abs(rho[:, None] - rho[None]) < 1e-6) & (np.abs(theta[:, None] - theta[None]) < 1e-6)
        keep = _nms(near, cfg.max_lines)
        return np.stack([rho[keep], theta[keep]], 1)

    def fit(self, lines: np.ndarray, X: np.ndarray, phi: np.ndarray, s: float):
        """Refits and candidate segments of Hough lines (N, 2).

        X: (P, 2) full-resolution edge pixels, phi: (P,) their gradient angles
        mod pi. Each line only looks at the pixels whose phi is within
        ``orientation_tol`` of its theta: phi is sorted once and the window is
        a slice (two at the wrap-around), so the work is sum_j |window_j|
        rather than P x N. Refinement (``refine``):

        1. fine local Hough: the voters (|R| <= rho_res/2 + 1/2) give a pivot
           q (their centroid); lines through q + o n(theta + delta), delta in
           +-fine_theta (step 0.01 rad), o in +-rho_res (1 px bins, summed in
           pairs) are voted on by the window's pixels; the best one wins. This
           keeps the support-maximising line where texture would bias a fit.
        2. TLS on the pixels with |R| <= 2 band, then <= band
           (band = max(refine_band, 1/s) px).

        Returns lines (N, 2), segments (N, 4) (NaN rows when a line kept < 2
        pixels) and support (N,) (pixels in the segment).
        """
        cfg = self.config
        N = len(lines)
        rho, theta = lines[:, 0].copy(), lines[:, 1].copy()
        ctr = X.mean(0)
        order = np.argsort(phi, kind="stable")
        ph, Xs = phi[order], X[order] - ctr
        tol = cfg.orientation_tol
        final = max(cfg.refine_band, 1.0 / s)
        if cfg.refine:
            rho, theta = self._fine_hough(rho, theta, Xs, ph, ctr)
        bands = [2.0 * final, final] if cfg.refine else [final]
        lid = idx = None
        for band in bands:
            lid, idx = self._windows(theta, ph, tol)
            if len(idx) == 0:
                break
            x, y = Xs[idx, 0], Xs[idx, 1]
            c, sn = np.cos(theta), np.sin(theta)
            rc = rho - c * ctr[0] - sn * ctr[1]
            m = np.abs(x * c[lid] + y * sn[lid] - rc[lid]) <= band
            lid, idx, x, y = lid[m], idx[m], x[m], y[m]
            if not cfg.refine:
                break
            cnt = np.bincount(lid, minlength=N).astype(float)
            ok = cnt >= 2
            if not ok.any():
                continue
            mom = [np.bincount(lid, weights=v, minlength=N)[ok] for v in (x, y, x * x, x * y, y * y)]
            r2, t2 = tls_from_moments(cnt[ok], *mom)
            r2 = r2 + np.cos(t2) * ctr[0] + np.sin(t2) * ctr[1]
            rho[ok], theta[ok] = canonical(r2, t2)
        segs = np.full((N, 4), np.nan)
        support = np.zeros(N, dtype=int)
        if idx is None or len(idx) == 0:
            return np.stack([rho, theta], 1), segs, support
        # longest run of inliers along each line, split at gaps > max_gap
        c, sn = np.cos(theta), np.sin(theta)
        t = (x + ctr[0]) * -sn[lid] + (y + ctr[1]) * c[lid]
        o = np.lexsort((t, lid))
        t, lid = t[o], lid[o]
        new_run = np.ones(len(t), dtype=bool)
        new_run[1:] = (np.diff(t) > cfg.max_gap) | (np.diff(lid) != 0)
        starts = np.flatnonzero(new_run)
        ends = np.append(starts[1:] - 1, len(t) - 1)
        extent = t[ends] - t[starts]
        run_line = lid[starts]
        # per line, the run with the largest extent (ties: first)
        ro = np.lexsort((-extent, run_line))
        first = np.ones(len(ro), dtype=bool)
        first[1:] = run_line[ro][1:] != run_line[ro][:-1]
        best = ro[first]
        j = run_line[best]
        t0, t1 = t[starts[best]], t[ends[best]]
        fx, fy = rho[j] * c[j], rho[j] * sn[j]
        segs[j] = np.stack([fx - t0 * sn[j], fy + t0 * c[j], fx - t1 * sn[j], fy + t1 * c[j]], 1)
        support[j] = ends[best] - starts[best] + 1
        segs[support < 2] = np.nan
        return np.stack([rho, theta], 1), segs, support

    def _fine_hough(self, rho, theta, Xs, ph, ctr):
        """Step 1 of :meth:`fit` (Xs: pixels centred on ctr, sorted by phi)."""
        cfg = self.config
        N = len(rho)
        lid, idx = self._windows(theta, ph, cfg.orientation_tol)
        if len(idx) == 0:
            return rho, theta
        x, y = Xs[idx, 0], Xs[idx, 1]
        c, sn = np.cos(theta), np.sin(theta)
        rc = rho - c * ctr[0] - sn * ctr[1]                  # lines in centred coordinates
        u = x * c[lid] + y * sn[lid] - rc[lid]                 # offset from the Hough line
        vote = np.abs(u) <= 0.5 * cfg.rho_res + 0.5
        cnt = np.bincount(lid[vote], minlength=N).astype(float)
        px = np.bincount(lid[vote], weights=x[vote], minlength=N) / np.maximum(cnt, 1)
        py = np.bincount(lid[vote], weights=y[vote], minlength=N) / np.maximum(cnt, 1)
        none = cnt == 0                                        # pivot: foot of the line
        px[none], py[none] = (rc * c)[none], (rc * sn)[none]
        R = float(cfg.rho_res)
        dmax = float(cfg.fine_theta)
        deltas = np.arange(-dmax, dmax + 1e-9, 0.01)
        qx, qy = x - px[lid], y - py[lid]
        u = qx * c[lid] + qy * sn[lid]
        v = -qx * sn[lid] + qy * c[lid]
        keep = np.abs(u) <= R + 1.0 + np.abs(v) * np.sin(dmax)
        u, v, lj = u[keep], v[keep], lid[keep]
        if len(u) == 0:
            return rho, theta
        nb = int(2 * R) + 1
        T = len(deltas)
        # offset bin b = floor(o + R) in [0, nb); stored as b + 1 with the two
        # outer bins (b < 0, b >= nb) catching what falls outside
        o = (u.astype(np.float32)[:, None] * np.cos(deltas).astype(np.float32)
             + v.astype(np.float32)[:, None] * np.sin(deltas).astype(np.float32))
        o += np.float32(R + 1.0)
        np.clip(o, 0.0, nb + 1.0, out=o)
        b = o.astype(np.int32)
        b += ((lj.astype(np.int32) * T)[:, None] + np.arange(T, dtype=np.int32)) * (nb + 2)
        acc = np.bincount(b.ravel(), minlength=N * T * (nb + 2)).reshape(N, T, nb + 2)[:, :, 1:-1]
        acc2 = acc[:, :, :-1] + acc[:, :, 1:]                  # 2-px windows, centre at bin edge
        best = acc2.reshape(N, -1).argmax(1)
        k, bo = np.divmod(best, nb - 1)
        has = acc2.reshape(N, -1).max(1) > 0
        th = theta + deltas[k]
        off = bo + 1.0 - R                                      # window centre offset (px)
        cn, snn = np.cos(th), np.sin(th)
        r_new = (px * cn + py * snn + off) + cn * ctr[0] + snn * ctr[1]
        r_new, th = canonical(r_new, th)
        return np.where(has, r_new, rho), np.where(has, th, theta)

    @staticmethod
    def _windows(theta: np.ndarray, ph: np.ndarray, tol: float | None):
        """(line id, index into ph) of the sorted-phi pixels within tol of each theta."""
        P = len(ph)
        los, his, ids = [], [], []
        for j, t in enumerate(theta):
            if tol is None or tol >= 0.5 * np.pi:
                parts = [(0.0, np.pi)]
            else:
                lo, hi = t - tol, t + tol
                parts = [(max(lo, 0.0), min(hi, np.pi))]
                if lo < 0:
                    parts.append((lo + np.pi, np.pi))
                if hi > np.pi:
                    parts.append((0.0, hi - np.pi))
            for lo, hi in parts:
                los.append(lo)
                his.append(hi)
                ids.append(j)
        a = np.searchsorted(ph, los, side="left")
        b = np.searchsorted(ph, his, side="right") if P else a
        n = np.maximum(b - a, 0)
        total = int(n.sum())
        if total == 0:
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        lid = np.repeat(np.asarray(ids), n)
        off = np.repeat(a - np.concatenate([[0], np.cumsum(n)[:-1]]), n)
        return lid, np.arange(total) + off

    # -- the detector ---------------------------------------------------------------
    def detect(self, image: np.ndarray, predicted_lines: np.ndarray | None = None,
               association: AssociationConfig | None = None) -> Detection:
        """Detect on an undistorted BGR (or grey) uint8 frame; ``predicted_lines``
        (2, 2) gate the association; ``association`` overrides the configured
        gates for this call (e.g. widened after a tracking loss)."""
        t_start = time.perf_counter()
        cfg = self.config
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
            gx = dx[ys, xs].astype(float)
            gy = dy[ys, xs].astype(float)
            phi = np.mod(np.arctan2(gy, gx), np.pi)
            lines = self.hough(edges, s, (H, W), xs, ys, phi)
        if len(lines):
            X = np.stack([(xs + 0.5) / s_x - 0.5, (ys + 0.5) / s_y - 0.5], 1)
            lines, segs, support = self.fit(lines, X, phi, s)
            length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
            good = np.isfinite(length) & (length >= cfg.min_length)
            lines, segs, length = lines[good], segs[good], length[good]
            order = np.argsort(-length, kind="stable")
            lines, segs, length = lines[order], segs[order], length[order]
            if len(lines) > 1:
                mid = 0.5 * (segs[:, :2] + segs[:, 2:])
                c, sn = np.cos(lines[:, 1]), np.sin(lines[:, 1])
                off = np.abs(c[:, None] * mid[None, :, 0] + sn[:, None] * mid[None, :, 1]
                             - lines[:, None, 0])            # [i, j]: midpoint j to line i
                _, dth = line_difference(lines[:, None, 0], lines[:, None, 1],
                                         lines[None, :, 0], lines[None, :, 1])
                near = (off <= cfg.cluster_rho) & (np.abs(dth) <= cfg.cluster_theta)
                keep = _nms(near, cfg.max_lines)
                lines, segs = lines[keep], segs[keep]
            det.segments = segs
            near_line = np.zeros((H, W), np.uint8)
            thick = max(1, int(round(2 * cfg.line_band + 1)))
            for x1, y1, x2, y2 in np.round(segs * 16).astype(np.int64):
                cv2.line(near_line, (int(x1), int(y1)), (int(x2), int(y2)), 1, thick, cv2.LINE_8, shift=4)
            big = big & (near_line * 255)
            a = associate(lines, segs, predicted_lines, association or cfg.association)
            det.shaft_lines, det.shaft_segments, det.edge_ids = a.lines, a.segments, a.edge_ids
        if len(lines) == 0:
            big = np.zeros_like(big)
        det.heatmap = (big > 0).astype(np.float32)
        det.ms = 1e3 * (time.perf_counter() - t_start)
        return det
