"""The learned detector: a tiny line / junction network at 1/4 scale, on one CPU core.

A small fully-convolutional net (:mod:`graphtrack.detect.learned_net`), trained
on domain-randomised simulated frames (:mod:`graphtrack.training`), predicts
SOLD2's two outputs, segments and a line heatmap H, at camera rate:

1. the undistorted BGR frame (H x W) is resized by ``scale`` (1/4: 540x960 ->
   135x240, cv2.INTER_AREA) and fed to the net, which returns the line
   heatmap L and the junction (endpoint) heatmap J at that size (sigmoids);
   given a RAW frame and its camera (``detect(..., camera=)``, what the tracking
   pipeline does), the frame is resized first and undistorted at 1/4 size;
2. segments are extracted at the reduced scale
   (:func:`graphtrack.detect.segments.extract_segments`);
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
   the heatmap's segments); only the moved segments get new lines, and
   ``Detection.refined`` (one flag per shaft segment) marks them, so that their
   pixel sets are carried onto them (:func:`graphtrack.detect.pixel_sets.carry_to_segment`)
   and the others' are known as bands (``Observation.bands``). H is left as
   the net made it.

When the predicted shaft lies near an image axis, where the shipped net does not see
it, the net's input is turned by 45 deg and its maps turned back
(:mod:`graphtrack.detect.turn`; ``turn=False`` keeps the input as it is).

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

import copy
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import torch

from graphtrack.detect.association import AssociationConfig, associate
from graphtrack.detect.base import Detection, detector_image
from graphtrack.detect.learned_net import ARCH, LineNet
from graphtrack.detect.markers import MarkerConfig, detect_markers
from graphtrack.detect.segments import ExtractConfig, extract_segments
from graphtrack.detect.subpixel import SubpixelConfig, refine_segments
from graphtrack.detect.turn import turn_for, turned, turned_back
from graphtrack.errors import InputError, one_line
from graphtrack.geometry.image_scale import scale_points
from graphtrack.geometry.lines import line_through

DEFAULT_WEIGHTS = Path(__file__).resolve().parent.parent / "data" / "learned_detector.pt"


def load_weights(path: str | Path | None = None):
    """The fused (inference) LineNet from a weights file; InputError when unusable."""
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise InputError(f"{path}: weights file not found")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is bad input
        msg = str(e).strip().splitlines()[0].split(". ")[0] if str(e).strip() else ""
        raise InputError(f"{path}: not a torch weights file (state dict) ({type(e).__name__}"
                         f"{': ' + msg if msg else ''})") from None
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
        raise InputError(f"{path}: weights do not fit the learned detector's architecture "
                         f"({ARCH}, width {width}): {one_line(e)[:160]}") from None
    return net.eval().fused()


#: traced inference nets per weights file (path, mtime, size): tracing costs 0.2-0.6 s once
_TRACED: dict = {}


def traced_net(net, key, shape: tuple[int, int]):
    """The fused ``net`` traced by torch.jit and frozen, in channels-last memory
    format, cached under ``key``; None when tracing fails (the caller keeps the eager net).

    The same conv kernels without the modules' Python overhead, and channels-last
    (NHWC) convolutions, which oneDNN runs faster on one core for this net's depthwise
    layers; logits within 1e-4 of the eager net's (summation order;
    docs/decisions/stereo-detection.md). Feed it ``channels_last`` input (any layout is
    correct, NHWC is the fast one). The decoder's sizes are traced as operations, so the
    trace serves any input size. The trace is not compared with the eager net here
    (``check_trace``: 0.6 s of imports at every start); tests/test_learned_detector.py
    compares them on several sizes."""
    if key not in _TRACED:
        try:
            with warnings.catch_warnings(), torch.inference_mode():
                warnings.simplefilter("ignore")   # torch.jit is deprecated, still supported
                nhwc = copy.deepcopy(net).to(memory_format=torch.channels_last)
                x = torch.zeros(1, 3, *shape).contiguous(memory_format=torch.channels_last)
                _TRACED[key] = torch.jit.freeze(torch.jit.trace(nhwc, x, check_trace=False))
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


class LearnedDetector:
    """``make_detector("learned", weights=None)``: see the module doc."""

    name = "learned"
    raw_input = True   #: detect(raw, ..., camera=...) works on raw frames (Pipeline uses it)

    def __init__(self, weights: str | Path | None = None, scale: float = 0.25, markers: bool = True,
                 extract: ExtractConfig | None = None, association: AssociationConfig | None = None,
                 marker_config: MarkerConfig | None = None, min_contrast: float = 2.0,
                 threads: int | None = None, subpixel: bool | SubpixelConfig = True, turn: bool = True):
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
        self.turn = bool(turn)
        if threads is not None:
            torch.set_num_threads(int(threads))

    def heatmaps(self, image: np.ndarray, camera=None, turn: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
        """(L, J) at the reduced scale for an undistorted BGR frame, or None
        when the frame is too small or uniform. camera: ``image`` is that camera's
        RAW frame; it is resized, then undistorted at the reduced size
        (:meth:`graphtrack.geometry.camera.Camera.undistort_resized`). turn (deg):
        the net reads the reduced frame turned by that much, its maps are turned back
        (:mod:`graphtrack.detect.turn`)."""
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
        if camera is not None:
            small = camera.undistort_resized(small)
        if float(cv2.meanStdDev(small.reshape(-1, 1))[1][0, 0]) < self.min_contrast:   # = small.std(), 20x faster
            return None
        if turn:
            canvas, A = turned(small, turn)
            L, J = self._net(canvas)
            return turned_back(L, A, small.shape[:2]), turned_back(J, A, small.shape[:2])
        return self._net(small)

    def _net(self, small: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The net's (L, J) sigmoid maps for a BGR uint8 image at the reduced scale."""
        x = torch.from_numpy(cv2.cvtColor(small, cv2.COLOR_BGR2RGB)).permute(2, 0, 1)[None].float() / 255.0
        x = x.contiguous(memory_format=torch.channels_last)   # HWC pixels are already NHWC
        if self._infer is None:
            self._infer = traced_net(self.net, self._net_key, small.shape[:2]) or self.net
        with torch.inference_mode():
            y = torch.sigmoid(self._infer(x))[0].numpy()
        return np.ascontiguousarray(y[0]), np.ascontiguousarray(y[1])   # no copy: the fused net's head is NCHW (Pointwise)

    def _markers(self, img: np.ndarray, camera) -> np.ndarray:
        """Marker centres (M, 2) in undistorted pixels (found on the raw frame with ``camera``)."""
        if not self.markers or img.ndim != 3:
            return np.zeros((0, 2))
        markers = detect_markers(img, self.marker_config)
        return camera.undistort_pixels(markers) if camera is not None and len(markers) else markers

    def detect(self, image: np.ndarray, predicted_lines: np.ndarray | None = None,
               association: AssociationConfig | None = None, camera=None) -> Detection:
        """Detect on an undistorted BGR uint8 frame; ``predicted_lines`` (2, 2) gate the
        association, ``association`` overrides the configured gates for this call.

        camera (a :class:`graphtrack.geometry.camera.Camera` of the frame's size):
        ``image`` is its RAW frame and the detection is in its undistorted pixels, made
        without undistorting the whole frame: the net's input is undistorted at the
        reduced size, markers are found on the raw frame and their centres undistorted,
        the sub-pixel refinement reads the raw frame through the distortion. Why:
        docs/decisions/stereo-detection.md."""
        t0 = time.perf_counter()
        img = detector_image(image)
        if camera is not None and not np.any(np.ravel(camera.dist)):
            camera = None                 # no distortion: raw pixels are undistorted ones
        markers = self._markers(img, camera)
        maps = self.heatmaps(img, camera, turn_for(predicted_lines) if self.turn else 0.0)
        if maps is None:
            return Detection(heatmap=np.zeros(img.shape[:2], np.float32), markers=markers,
                             ms=(time.perf_counter() - t0) * 1e3)
        L, J = maps
        h, w = img.shape[:2]
        seg_s, _ = extract_segments(L, J, self.extract)
        sx, sy = w / L.shape[1], h / L.shape[0]
        seg = scale_points(np.reshape(seg_s, (-1, 4)), sx, sy)
        H = cv2.resize(L, (w, h), interpolation=cv2.INTER_LINEAR)
        det = Detection(segments=seg, heatmap=H, markers=markers)
        if len(seg):
            self._shaft(det, img, predicted_lines, association or self.association, camera)
        det.ms = (time.perf_counter() - t0) * 1e3
        return det

    def _shaft(self, det: Detection, img: np.ndarray, predicted_lines, association, camera) -> None:
        """The shaft edges of ``det``: associated segments, moved onto the image's edge."""
        rho, theta = line_through(det.segments[:, :2], det.segments[:, 2:])
        assoc = associate(np.stack([rho, theta], 1), det.segments, predicted_lines, association)
        det.shaft_segments = assoc.segments
        det.shaft_lines = assoc.lines
        det.edge_ids = assoc.edge_ids
        det.refined = np.zeros(len(assoc.segments), bool)   # the heatmap's bands, until moved
        if self.subpixel is None or not len(assoc.segments):
            return
        refined = refine_segments(img, assoc.segments, self.subpixel, camera)
        moved = np.all(np.isfinite(refined), axis=1) & np.any(refined != assoc.segments, axis=1)
        if moved.any():
            rho, theta = line_through(refined[moved, :2], refined[moved, 2:])
            det.shaft_segments = refined
            det.shaft_lines = assoc.lines.copy()
            det.shaft_lines[moved] = np.stack([rho, theta], 1)
            det.refined = moved
