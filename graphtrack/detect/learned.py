"""The learned detector: a tiny line / junction network at 1/4 scale, on one CPU core.

A small fully-convolutional net (:mod:`graphtrack.detect.learned_net`), trained
on domain-randomised simulated frames (:mod:`graphtrack.training`), predicts
SOLD2's two outputs, segments and a line heatmap H, at camera rate:

1. the undistorted BGR frame (H x W) is resized by ``scale`` (1/4: 540x960 ->
   135x240, cv2.INTER_AREA) and fed to the net, which returns the line
   heatmap L and the junction (endpoint) heatmap J at that size (sigmoids);
2. segments are extracted at the reduced scale: probabilistic Hough
   (cv2.HoughLinesP) on {L >= line_threshold} proposes candidates; each is
   refined by a heatmap-weighted total-least-squares line fit to the
   above-threshold pixels within ``fit_band`` px of it, grown along the fitted
   line over all such pixels (split at gaps > ``max_gap``: the run holding the
   candidate's centre) and refitted; its extent is that of its supporting
   pixels, and each endpoint snaps to a junction peak (3x3 local maximum of
   J >= junction_threshold) within ``snap`` px of it along the line;
   near-duplicates (angle < 0.05 rad, offset < 2 px, overlapping) keep the
   best supported one;
3. segments go back to full-resolution undistorted pixels,
   x = (x_s + 0.5) / scale_x - 0.5 (pixel centres, OpenCV's resize
   convention), and H is L upsampled to H x W with cv2.INTER_LINEAR (the same
   convention), so the pixel sets of :mod:`graphtrack.detect.pixel_sets`
   index it at full resolution;
4. the shaft edges come from the shared association
   (:func:`graphtrack.detect.association.associate`) and the markers from the
   shared colour detector (:func:`graphtrack.detect.markers.detect_markers`);
5. each associated shaft segment is moved onto the image's edge at full
   resolution (:mod:`graphtrack.detect.subpixel`; ``subpixel=False`` keeps
   the heatmap's segments); only the moved segments get new lines. H is left
   as the net made it.

Weights: ``graphtrack/data/learned_detector.pt`` (shipped), or ``weights=FILE``
(from ``graphtrack train``), loaded with ``torch.load(weights_only=True)``; a
missing file, a file that is not a state dict, or one of another architecture
raises :class:`graphtrack.errors.InputError` naming the file.

Uniform frames (black, white: pixel standard deviation < ``min_contrast``) and
frames too small for the net (reduced side < 8 px) give an empty Detection.

Why a learned detector, and measurements: docs/decisions/learned-detector.md,
docs/decisions/subpixel-edges.md.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from graphtrack.detect.association import AssociationConfig, associate
from graphtrack.detect.base import Detection
from graphtrack.detect.learned_net import ARCH, LineNet
from graphtrack.detect.markers import MarkerConfig, detect_markers
from graphtrack.detect.subpixel import SubpixelConfig, refine_segments
from graphtrack.errors import InputError
from graphtrack.geometry.lines import line_through

DEFAULT_WEIGHTS = Path(__file__).resolve().parent.parent / "data" / "learned_detector.pt"


@dataclass
class ExtractConfig:
    """Segment extraction at the reduced scale (px of the reduced image)."""

    line_threshold: float = 0.5       #: L >= this is a line pixel
    junction_threshold: float = 0.3   #: J peaks above this are junctions
    hough_votes: int = 12             #: cv2.HoughLinesP threshold
    min_length: float = 8.0           #: px (reduced), shorter segments dropped
    max_gap: float = 4.0              #: px (reduced), HoughLinesP maxLineGap
    fit_band: float = 1.5             #: px (reduced), pixels used by the line fit
    min_support: int = 8              #: supporting pixels needed
    snap: float = 3.0                 #: px (reduced), endpoint-to-junction snap radius
    max_segments: int = 32


def load_weights(path: str | Path | None = None):
    """The fused (inference) LineNet from a weights file; InputError when unusable."""
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise InputError(f"{path}: weights file not found")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is bad input
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"{path}: not a torch weights file (state dict) ({msg[:120]})") from None
    meta = {}
    if isinstance(obj, dict) and "state_dict" in obj:
        meta = {k: v for k, v in obj.items() if k != "state_dict"}
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not obj or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise InputError(f"{path}: not a state dict of the learned detector (expected a dict of tensors)")
    if not isinstance(meta.get("arch", ARCH), str) or meta.get("arch", ARCH) != ARCH:
        raise InputError(f"{path}: weights of architecture '{meta.get('arch')}', expected '{ARCH}'")
    width, stem = check_meta(meta, path)
    net = LineNet(width, stem)
    try:
        net.load_state_dict(obj, strict=True)
    except (RuntimeError, KeyError, ValueError) as e:
        first = str(e).strip().splitlines()[0]
        raise InputError(f"{path}: weights do not fit the learned detector's architecture "
                         f"({ARCH}, width {width}): {first[:160]}") from None
    return net.eval().fused()


#: traced inference nets per weights file (path, mtime, size): tracing costs 0.2-0.6 s once
_TRACED: dict = {}


def traced_net(net, key, shape: tuple[int, int]):
    """The fused ``net`` traced by torch.jit and frozen, cached under ``key``; None when
    tracing fails (the caller keeps the eager net).

    The same conv kernels without the modules' Python overhead: 4.4 vs 5.9 ms per
    135x240 image on one core, outputs bit-identical to the eager net
    (tests/test_learned_detector.py). The decoder's sizes are traced as operations, so
    the trace serves any input size."""
    if key not in _TRACED:
        try:
            with warnings.catch_warnings(), torch.inference_mode():
                warnings.simplefilter("ignore")   # torch.jit is deprecated, still supported
                _TRACED[key] = torch.jit.freeze(torch.jit.trace(net, torch.zeros(1, 3, *shape)))
        except Exception:  # noqa: BLE001 - any tracing failure: run the eager net
            _TRACED[key] = None
    return _TRACED[key]


#: the largest channel counts a weights file may ask for (the shipped net: width 16, stem 8)
MAX_WIDTH, MAX_STEM = 256, 128


def check_meta(meta: dict, path: Path) -> tuple[int, int]:
    """(width, stem) from a weights file's metadata, each an int in 1..MAX_*; InputError
    naming the file and the key otherwise (a width of 10**6 would allocate terabytes)."""
    out = []
    for key, default, top in (("width", 16, MAX_WIDTH), ("stem", 8, MAX_STEM)):
        v = meta.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= top:
            raise InputError(f"{path}: metadata '{key}' must be an integer in 1..{top}, got {v!r}")
        out.append(v)
    return out[0], out[1]


def _tls(Q: np.ndarray, wq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted total-least-squares line: (centroid, unit direction)."""
    c = (wq[:, None] * Q).sum(0) / wq.sum()
    X = Q - c
    _, evecs = np.linalg.eigh((wq[:, None] * X).T @ X)
    return c, evecs[:, 1]


def _junction_peaks(J: np.ndarray, thr: float) -> np.ndarray:
    """(n, 2) (x, y) of 3x3 local maxima of J >= thr (reduced px)."""
    dil = cv2.dilate(J, np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero((J >= thr) & (J >= dil))
    return np.stack([xs, ys], 1).astype(float)


def _grow_and_fit(P: np.ndarray, w: np.ndarray, a: np.ndarray, b: np.ndarray, cfg: ExtractConfig):
    """One Hough candidate a -> b refined (module doc, step 2): (centroid c, unit
    direction u, supporting pixels' indices into P) of the refitted line, or None."""
    d = b - a
    n = np.hypot(*d)
    if n < 1e-9:
        return None
    d /= n
    nrm = np.array([-d[1], d[0]])
    Pa = P - a
    r = Pa @ nrm
    t = Pa @ d
    sel = (np.abs(r) <= cfg.fit_band) & (t >= -cfg.max_gap) & (t <= n + cfg.max_gap)
    if np.count_nonzero(sel) < cfg.min_support:
        return None
    c, u = _tls(P[sel], w[sel])
    # grow along the fitted line: all pixels in the band, split at gaps,
    # keep the run holding the candidate's centre (else the longest), refit
    X = P - c
    band = np.abs(X @ np.array([-u[1], u[0]])) <= cfg.fit_band
    tq = X[band] @ u
    order = np.argsort(tq)
    ts = tq[order]
    gaps = np.flatnonzero(ts[1:] - ts[:-1] > cfg.max_gap)
    starts = np.concatenate(([0], gaps + 1))
    ends = np.concatenate((gaps, [len(ts) - 1]))
    tc = (0.5 * (a + b) - c) @ u
    hold = np.flatnonzero((ts[starts] <= tc) & (ts[ends] >= tc))
    k = int(hold[0]) if len(hold) else int(np.argmax(ts[ends] - ts[starts]))
    cnt = ends[k] - starts[k] + 1
    if ts[ends[k]] - ts[starts[k]] < cfg.min_length or cnt < cfg.min_support:
        return None
    run = np.flatnonzero(band)[order[starts[k]:ends[k] + 1]]
    c, u = _tls(P[run], w[run])
    return c, u, run


def _snap(e: np.ndarray, c: np.ndarray, u: np.ndarray, peaks: np.ndarray, cfg: ExtractConfig) -> np.ndarray:
    """Endpoint e on the line (c, u) moved to the projection of the nearest junction
    peak within ``snap`` px (and ``fit_band`` + 0.5 px of the line); else e."""
    dp = peaks - e
    along = dp @ u
    perp = np.abs(dp @ np.array([-u[1], u[0]]))
    ok = (np.hypot(along, perp) <= cfg.snap) & (perp <= cfg.fit_band + 0.5)
    if not ok.any():
        return e
    j = np.flatnonzero(ok)[np.argmin(np.hypot(along, perp)[ok])]
    return c + ((peaks[j] - c) @ u) * u  # project onto the fitted line


def _duplicate(S: np.ndarray, i: int, keep: list[int]) -> bool:
    """Segment i near-duplicates a kept one: angle < 0.05 rad, midpoint < 2 px from
    its line, overlapping by more than 0.3 of the shorter."""
    a, b = S[i, :2], S[i, 2:]
    mid = 0.5 * (a + b)
    di = (b - a) / max(np.hypot(*(b - a)), 1e-9)
    for j in keep:
        aj, bj = S[j, :2], S[j, 2:]
        dj = (bj - aj) / max(np.hypot(*(bj - aj)), 1e-9)
        if abs(di @ dj) < np.cos(0.05):
            continue
        nj = np.array([-dj[1], dj[0]])
        if abs((mid - aj) @ nj) > 2.0:
            continue
        ta, tb = sorted(((a - aj) @ dj, (b - aj) @ dj))
        lj = np.hypot(*(bj - aj))
        if min(tb, lj) - max(ta, 0.0) > 0.3 * min(tb - ta, lj):
            return True
    return False


def extract_segments(L: np.ndarray, J: np.ndarray | None = None,
                     config: ExtractConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Segments (S, 4) (x1, y1, x2, y2) and their support (S,) from a line
    heatmap L (h, w) in [0, 1] and an optional junction heatmap J, in the
    heatmaps' own pixels (see the module doc, step 2)."""
    cfg = config or ExtractConfig()
    L = np.asarray(L, np.float32)
    empty = np.zeros((0, 4)), np.zeros(0)
    if L.ndim != 2 or min(L.shape) < 2:
        return empty
    mask = (L >= cfg.line_threshold).astype(np.uint8)
    ys, xs = np.nonzero(mask)
    if len(xs) < cfg.min_support:
        return empty
    hl = cv2.HoughLinesP(mask, 1, np.pi / 180, cfg.hough_votes, minLineLength=cfg.min_length,
                         maxLineGap=cfg.max_gap)
    if hl is None:
        return empty
    cand = hl.reshape(-1, 4).astype(float)
    cand = cand[np.argsort(-np.hypot(cand[:, 2] - cand[:, 0], cand[:, 3] - cand[:, 1]), kind="stable")]
    cand = cand[: 4 * cfg.max_segments]
    P = np.stack([xs, ys], 1).astype(float)
    w = L[ys, xs].astype(float)
    peaks = _junction_peaks(np.asarray(J, np.float32), cfg.junction_threshold) if J is not None \
        else np.zeros((0, 2))
    out, support = [], []
    for x1, y1, x2, y2 in cand:
        fit = _grow_and_fit(P, w, np.array([x1, y1]), np.array([x2, y2]), cfg)
        if fit is None:
            continue
        c, u, run = fit
        tq = (P[run] - c) @ u
        e0, e1 = c + float(tq.min()) * u, c + float(tq.max()) * u
        if len(peaks):
            e0, e1 = _snap(e0, c, u, peaks, cfg), _snap(e1, c, u, peaks, cfg)
        out.append(np.concatenate((e0, e1)))
        support.append(float(w[run].sum()))
    if not out:
        return empty
    S = np.array(out)
    sup = np.array(support)
    order = np.argsort(-sup, kind="stable")
    S, sup = S[order], sup[order]
    keep: list[int] = []
    for i in range(len(S)):
        if not _duplicate(S, i, keep):
            keep.append(i)
        if len(keep) >= cfg.max_segments:
            break
    return S[keep], sup[keep]


class LearnedDetector:
    """``make_detector("learned", weights=None)``: see the module doc."""

    name = "learned"

    def __init__(self, weights: str | Path | None = None, scale: float = 0.25, markers: bool = True,
                 extract: ExtractConfig | None = None, association: AssociationConfig | None = None,
                 marker_config: MarkerConfig | None = None, min_contrast: float = 2.0,
                 threads: int | None = None, subpixel: bool | SubpixelConfig = True):
        self.net = load_weights(weights)
        path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
        st = path.stat()
        self._net_key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
        self._infer = None            # the traced net, made at the first frame
        self.scale = float(scale)
        self.markers = markers
        self.extract = extract or ExtractConfig()
        self.association = association or AssociationConfig()
        self.marker_config = marker_config
        self.min_contrast = float(min_contrast)
        self.subpixel = subpixel if isinstance(subpixel, SubpixelConfig) else (SubpixelConfig() if subpixel else None)
        if threads is not None:
            torch.set_num_threads(int(threads))

    def heatmaps(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(L, J) at the reduced scale for an undistorted BGR frame, or None
        when the frame is too small or uniform."""
        img = np.asarray(image)
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        if img.ndim != 3 or img.shape[2] < 3 or min(img.shape[:2]) < 1:
            return None
        if img.dtype != np.uint8:
            img = np.clip(img, 0, 255).astype(np.uint8)
        h, w = img.shape[:2]
        hs, ws = int(round(h * self.scale)), int(round(w * self.scale))
        if min(hs, ws) < 8:
            return None
        small = cv2.resize(img[:, :, :3], (ws, hs), interpolation=cv2.INTER_AREA)
        if float(small.std()) < self.min_contrast:
            return None
        x = torch.from_numpy(cv2.cvtColor(small, cv2.COLOR_BGR2RGB)).permute(2, 0, 1)[None].float() / 255.0
        if self._infer is None:
            self._infer = traced_net(self.net, self._net_key, small.shape[:2]) or self.net
        with torch.inference_mode():
            y = torch.sigmoid(self._infer(x))[0].numpy()
        return y[0], y[1]

    def detect(self, image: np.ndarray, predicted_lines: np.ndarray | None = None,
               association: AssociationConfig | None = None) -> Detection:
        """Detect on an undistorted BGR uint8 frame; ``predicted_lines`` (2, 2) gate the
        association, ``association`` overrides the configured gates for this call."""
        t0 = time.perf_counter()
        img = np.asarray(image)
        markers = np.zeros((0, 2))
        if self.markers and img.ndim == 3:
            markers = detect_markers(img, self.marker_config)
        maps = self.heatmaps(img)
        if maps is None:
            H = None
            if img.ndim >= 2 and min(img.shape[:2]) >= 1:
                H = np.zeros(img.shape[:2], np.float32)
            return Detection(heatmap=H, markers=markers, ms=(time.perf_counter() - t0) * 1e3)
        L, J = maps
        h, w = img.shape[:2]
        seg_s, _ = extract_segments(L, J, self.extract)
        sx, sy = w / L.shape[1], h / L.shape[0]
        seg = np.zeros((len(seg_s), 4))
        if len(seg_s):
            seg[:, 0::2] = (seg_s[:, 0::2] + 0.5) * sx - 0.5
            seg[:, 1::2] = (seg_s[:, 1::2] + 0.5) * sy - 0.5
        H = cv2.resize(L, (w, h), interpolation=cv2.INTER_LINEAR)
        det = Detection(segments=seg, heatmap=H, markers=markers)
        if len(seg):
            rho, theta = line_through(seg[:, :2], seg[:, 2:])
            lines = np.stack([rho, theta], 1)
            assoc = associate(lines, seg, predicted_lines, association or self.association)
            det.shaft_segments = assoc.segments
            det.shaft_lines = assoc.lines
            det.edge_ids = assoc.edge_ids
            if self.subpixel is not None and len(assoc.segments):
                refined = refine_segments(img, assoc.segments, self.subpixel)
                moved = np.all(np.isfinite(refined), axis=1) & np.any(refined != assoc.segments, axis=1)
                if moved.any():
                    rho, theta = line_through(refined[moved, :2], refined[moved, 2:])
                    det.shaft_segments = refined
                    det.shaft_lines = assoc.lines.copy()
                    det.shaft_lines[moved] = np.stack([rho, theta], 1)
        det.ms = (time.perf_counter() - t0) * 1e3
        return det
