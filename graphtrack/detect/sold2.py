"""The method's own line detector: SOLD2 (kornia.feature.SOLD2_detector) as a graphtrack Detector.

``make_detector("sold2", weights=FILE)``: the user supplies the checkpoint
(no network access at run time: the detector is built with
``pretrained=False`` and the file's state dict is loaded). Accepted files,
read with ``torch.load(weights_only=True)``:

- the released SOLD2 checkpoint (a dict with ``model_state_dict``, e.g.
  ``sold2_wireframe.tar``), adapted with kornia's ``adapt_state_dict``;
- a plain state dict of kornia's ``SOLD2Net`` (``SOLD2_detector.model``).

A missing file, one that is not a state dict, or one of another architecture
raises :class:`graphtrack.errors.InputError` naming the file.

Per frame: the undistorted BGR image -> grey in [0, 1] (optionally resized by
``scale``), zero-padded to multiples of 8, through SOLD2; its segments
((row, col) endpoints) become (x1, y1, x2, y2) in full-resolution undistorted
px, x = (x_s + 0.5) / scale - 0.5; its line heatmap, cropped and clipped to
[0, 1], resized to the full image (cv2.INTER_LINEAR), is H. Shaft edges come
from the shared association, markers from the shared colour detector.
SOLD2 is slow on a CPU (about 1-2 frames/s at 540x960, as in the method).
"""
from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import torch

from graphtrack.detect.association import AssociationConfig, associate
from graphtrack.detect.base import Detection, detector_image
from graphtrack.detect.markers import MarkerConfig, detect_markers
from graphtrack.errors import InputError
from graphtrack.geometry.image_scale import scale_points
from graphtrack.geometry.lines import line_through


def build_sold2(weights: str | Path | None, config=None):
    """kornia SOLD2_detector (eval) with the state dict of ``weights`` loaded;
    ``weights=None`` keeps the random initialisation (tests only)."""
    from kornia.feature import SOLD2_detector  # lazy: kornia takes seconds to import, SOLD2 only

    det = SOLD2_detector(pretrained=False, config=config)
    if weights is None:
        return det.eval()
    path = Path(weights)
    if not path.is_file():
        raise InputError(f"{path}: SOLD2 weights file not found")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is bad input
        msg = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise InputError(f"{path}: not a torch checkpoint / state dict ({msg[:120]})") from None
    if isinstance(obj, dict) and "model_state_dict" in obj:
        obj = obj["model_state_dict"]
        if isinstance(obj, dict):
            try:
                obj = det.adapt_state_dict(dict(obj))
            except Exception as e:  # noqa: BLE001
                raise InputError(f"{path}: not a SOLD2 checkpoint ({str(e)[:120]})") from None
    if not isinstance(obj, dict) or not obj or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise InputError(f"{path}: not a state dict of SOLD2 (expected a dict of tensors)")
    try:
        det.model.load_state_dict(obj, strict=True)
    except (RuntimeError, KeyError, ValueError) as e:
        first = (str(e).strip().splitlines() or [""])[0]
        raise InputError(f"{path}: weights do not fit kornia's SOLD2 architecture: {first[:160]}") from None
    return det.eval()


class Sold2Detector:
    """``make_detector("sold2", weights=FILE)``: see the module doc."""

    name = "sold2"

    def __init__(self, weights: str | Path | None = None, scale: float = 1.0, markers: bool = True,
                 association: AssociationConfig | None = None, marker_config: MarkerConfig | None = None,
                 random_init: bool = False, config=None):
        if weights is None and not random_init:
            raise InputError("--detector sold2 needs --weights FILE (a SOLD2 checkpoint, e.g. sold2_wireframe.tar)")
        self.det = build_sold2(None if random_init else weights, config)
        self.scale = float(scale)
        self.markers = markers
        self.association = association or AssociationConfig()
        self.marker_config = marker_config

    def detect(self, image: np.ndarray, predicted_lines: np.ndarray | None = None,
               association: AssociationConfig | None = None) -> Detection:
        """Detect on an undistorted BGR uint8 frame; ``predicted_lines`` (2, 2) gate the
        association, ``association`` overrides the configured gates for this call."""
        t0 = time.perf_counter()
        img = detector_image(image)
        gray = img if img.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)
        h, w = gray.shape
        markers = detect_markers(img, self.marker_config) if (self.markers and img.ndim == 3) else np.zeros((0, 2))
        hs, ws = max(1, int(round(h * self.scale))), max(1, int(round(w * self.scale)))
        if min(hs, ws) < 16 or float(gray.std()) < 2.0:
            return Detection(heatmap=np.zeros((h, w), np.float32), markers=markers,
                             ms=(time.perf_counter() - t0) * 1e3)
        small = gray if (hs, ws) == (h, w) else cv2.resize(gray, (ws, hs), interpolation=cv2.INTER_AREA)
        H8, W8 = -(-hs // 8) * 8, -(-ws // 8) * 8
        x = torch.zeros(1, 1, H8, W8)
        x[0, 0, :hs, :ws] = torch.from_numpy(small).float() / 255.0
        with torch.inference_mode():
            out = self.det(x)
        heat = out["line_heatmap"][0, :hs, :ws].clamp(0, 1).numpy().astype(np.float32)
        seg_rc = out["line_segments"][0].reshape(-1, 2, 2).numpy().astype(float)   # (N, 2, (row, col))
        seg = seg_rc[:, :, ::-1].reshape(-1, 4)                                      # (x1, y1, x2, y2)
        inside = np.all((seg[:, 0::2] <= ws - 0.5) & (seg[:, 1::2] <= hs - 0.5), axis=1)
        seg = seg[inside]
        sx, sy = w / ws, h / hs
        seg = scale_points(seg, sx, sy)
        H = heat if (hs, ws) == (h, w) else cv2.resize(heat, (w, h), interpolation=cv2.INTER_LINEAR)
        det = Detection(segments=seg, heatmap=H, markers=markers)
        if len(seg):
            rho, theta = line_through(seg[:, :2], seg[:, 2:])
            keep = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > 0
            seg, lines = seg[keep], np.stack([rho, theta], 1)[keep]
            det.segments = seg
            a = associate(lines, seg, predicted_lines, association or self.association)
            det.shaft_segments, det.shaft_lines, det.edge_ids = a.segments, a.lines, a.edge_ids
        det.ms = (time.perf_counter() - t0) * 1e3
        return det
