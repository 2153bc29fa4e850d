"""What detectors return and what estimators consume.

All pixel coordinates here are UNDISTORTED pixels of the left camera (the
tracking loop undistorts each raw frame once before detection). Lines follow
:mod:`graphtrack.geometry.lines`: cos(theta) x + sin(theta) y = rho.

Vocabulary of the method:
- segments: candidate line segments (x1, y1, x2, y2);
- heatmap H in [0, 1]^{H x W}: the line heatmap (the learned detector's
  output; for Canny, the binary edge map);
- shaft edges: the (at most two) segments associated with the insertion
  shaft's two silhouette lines, endpoints e^a_{1,2}, e^b_{1,2};
- endpoint set E_e(e) = {p : |p - e| <= alpha, H(p) >= beta};
- line set E_l(e^a, e^b) = {p : dist(p, segment) <= alpha, H(p) >= beta};
- markers: painted-marker blob centroids.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: The method's six observation models (``--observation``).
OBSERVATION_MODELS = (
    "canny",
    "endpoints-polar",
    "endpoint-intensities-polar",
    "line-intensities-polar",
    "endpoint-intensities",
    "line-intensities",
)
#: Which of them score in line-parameter space (rho, theta); the rest score pixels.
POLAR_MODELS = ("canny", "endpoints-polar", "endpoint-intensities-polar", "line-intensities-polar")


def detector_image(image) -> np.ndarray:
    """``image`` as the detectors read it: uint8 (H, W) grey or (H, W, 3) BGR (a single
    channel's third axis dropped, an alpha channel left out). ValueError naming what is
    wrong for anything else: another dtype (a 16-bit or float image is not scaled here:
    scale it to 0..255 first, e.g. ``(img >> 8).astype(np.uint8)`` for 16-bit), another
    shape, or an empty image."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"detector expects an 8-bit image (uint8, 0..255), got {img.dtype}: scale it first, "
                         "e.g. (img >> 8).astype(np.uint8) for 16-bit or (img * 255).astype(np.uint8) for 0..1")
    if img.ndim == 3 and img.shape[2] in (1, 3, 4):
        img = img[:, :, 0] if img.shape[2] == 1 else img[:, :, :3]
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)):
        raise ValueError(f"detector expects an (H, W) grey or (H, W, 3) BGR image, got shape {img.shape}")
    if min(img.shape[:2]) < 1:
        raise ValueError(f"detector got an empty image (shape {img.shape})")
    return img


def _empty(*shape) -> np.ndarray:
    return np.zeros((0,) + shape, dtype=float)


def _empty_ids() -> np.ndarray:
    return np.zeros(0, dtype=int)


@dataclass
class Detection:
    """One frame's detector output (undistorted pixels).

    segments: (S, 4) all candidate segments.
    heatmap: (H, W) float32 line heatmap in [0, 1] or None.
    shaft_segments: (k, 4), k in {0, 1, 2}: segments associated with the
        shaft's edges, endpoints (x1, y1, x2, y2).
    shaft_lines: (k, 2) (rho, theta) of those edges.
    markers: (M, 2) marker centroids.
    ms: milliseconds the detector spent.
    edge_ids: (k,) int: which predicted shaft edge (row of ``predicted_lines``)
        each of shaft_segments / shaft_lines belongs to; without a prediction,
        0 and 1 in a deterministic but arbitrary order
        (:mod:`graphtrack.detect.association`).
    refined: (k,) bool: which shaft segments a sub-pixel refinement moved onto the
        image's edge (:mod:`graphtrack.detect.subpixel`); their heatmap pixel sets are
        carried onto them (:func:`graphtrack.detect.pixel_sets.carry_to_segment`). A
        detector whose heatmap is a band that may lie off the edge (the learned net's)
        sets it for every shaft segment; its False entries make their pixel sets
        *bands* (:class:`Observation`). Empty or of another length: the detector does
        not say; nothing is carried and no set is a band (the Canny detector's sets
        lie on its edges).
    """

    segments: np.ndarray = field(default_factory=lambda: _empty(4))
    heatmap: np.ndarray | None = None
    shaft_segments: np.ndarray = field(default_factory=lambda: _empty(4))
    shaft_lines: np.ndarray = field(default_factory=lambda: _empty(2))
    markers: np.ndarray = field(default_factory=lambda: _empty(2))
    ms: float = 0.0
    edge_ids: np.ndarray = field(default_factory=_empty_ids)
    refined: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


@dataclass
class Observation:
    """What an estimator consumes for one frame, built from a Detection by
    :func:`graphtrack.detect.observe.make_observation` for one observation model.

    model: one of OBSERVATION_MODELS.
    lines: (k, 2) detected shaft lines (rho, theta) for the polar models
        (empty for the pixel models).
    pixels: per detected shaft edge, an (m_i, 2) pixel set (E_e or E_l) for the
        pixel models (empty list for the polar models).
    markers: (M, 2) detected marker centroids (empty when markers are off).
    edge_ids: (k,) int, which shaft edge each row of ``lines`` (polar models)
        or each entry of ``pixels`` (pixel models) belongs to (as in Detection).
    bands: per entry of ``pixels``, True where the set is a heatmap band that no
        sub-pixel refinement moved onto the image's edge (``Detection.refined``
        False), so it may sit a few px off the silhouette; empty: none. The
        particle filter and the smoother's and batch's pixel factors weigh such a
        set's pixels by ``band_weight`` (docs/decisions/band-weight.md).
    shaft_end: (k, 4), k in {0, 1}: the shaft's detected distal end (x, y) and the
        unit image direction (dx, dy) towards the wrist (:mod:`graphtrack.detect.shaft_end`),
        full-size undistorted px; empty when not found or not asked for.
    """

    model: str
    lines: np.ndarray = field(default_factory=lambda: _empty(2))
    pixels: list[np.ndarray] = field(default_factory=list)
    markers: np.ndarray = field(default_factory=lambda: _empty(2))
    edge_ids: np.ndarray = field(default_factory=_empty_ids)
    bands: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    shaft_end: np.ndarray = field(default_factory=lambda: _empty(4))

    @property
    def pixel_bands(self) -> np.ndarray:
        """``bands`` as one flag per entry of ``pixels`` (all False when the
        observation marks none, or not one flag per set)."""
        b = np.asarray(self.bands, bool).ravel()
        return b if len(b) == len(self.pixels) else np.zeros(len(self.pixels), bool)

    @property
    def has_shaft(self) -> bool:
        return len(self.lines) > 0 or any(len(p) > 0 for p in self.pixels)

    @property
    def empty(self) -> bool:
        return not self.has_shaft and len(self.markers) == 0


class Detector(Protocol):
    """Per-frame shaft and marker detector on undistorted images."""

    name: str

    def detect(self, image: np.ndarray, predicted_lines: np.ndarray | None = None,
               association=None) -> Detection:
        """image: undistorted BGR uint8 (H, W, 3). predicted_lines: (2, 2)
        (rho, theta) of the shaft edges projected from the current estimate of
        E, used to gate the association (None: no gate); association: an
        :class:`graphtrack.detect.association.AssociationConfig` overriding the
        detector's gates for this call.

        A detector with ``raw_input = True`` (the learned one) also takes
        ``camera=``: ``image`` is then that camera's RAW frame and the detection is
        still in its undistorted pixels (:func:`detect_raw`)."""
        ...  # pragma: no cover - protocol


def detect_raw(detector, image: np.ndarray, camera, predicted_lines: np.ndarray | None = None,
               association=None) -> Detection:
    """Detect on ``camera``'s RAW frame, in its undistorted pixels, as tracking does: a
    detector that reads raw frames (``raw_input``) gets the frame and the camera and
    undistorts only what it uses; any other gets ``camera.undistort(image)``."""
    if getattr(detector, "raw_input", False):
        return detector.detect(image, predicted_lines, association, camera=camera)
    return detector.detect(camera.undistort(image), predicted_lines, association)
