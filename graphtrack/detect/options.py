"""How frames become observations, as the CLI, the studies and the benchmarks choose it:
:class:`DetectionOptions`, each default written once (alpha / beta in :mod:`.pixel_sets`)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.detect.pixel_sets import ALPHA, BETA
from graphtrack.errors import InputError

#: px, the widest pixel-set radius accepted (ten times the method's)
MAX_ALPHA = 100.0

DETECTOR = "learned"                    #: the shipped CPU line network
OBSERVATION = "line-intensities"        #: the method's default observation model
MAX_DETECT_WIDTH = 960                  #: px; detection runs at most this wide by default


@dataclass(frozen=True)
class DetectionOptions:
    """detector: a registered detector name (:data:`graphtrack.detect.DETECTORS`);
    weights: its weights file (None: the shipped ones); alpha (px) / beta: the
    pixel sets' radius and heatmap threshold; markers: use painted-marker
    detections; scale: detect on the undistorted image scaled by this factor
    (None: at most MAX_DETECT_WIDTH px wide); shaft_end: find the shaft's distal end
    where robot.json gives it (:mod:`graphtrack.detect.shaft_end`); turn: the learned
    detector turns its net's input by 45 deg where the predicted shaft lies near an image
    axis (:mod:`graphtrack.detect.turn`)."""

    detector: str = DETECTOR
    weights: str | None = None
    alpha: float = ALPHA
    beta: float = BETA
    markers: bool = True
    scale: float | None = None
    shaft_end: bool = True
    turn: bool = True

    def check(self) -> DetectionOptions:
        """Raise InputError naming the CLI option of a value out of range; return self."""
        if self.scale is not None and not 0.05 <= self.scale <= 1.0:
            raise InputError("--detect-scale must be in [0.05, 1]")
        if not 0 < self.alpha <= MAX_ALPHA:   # wider: the pixel sets take in the image around the shaft
            raise InputError(f"--alpha must be in (0, {MAX_ALPHA:g}] px (the method's is {ALPHA:g}), "
                             f"got {self.alpha!r}")
        if not 0 <= self.beta <= 1:   # a heatmap value: outside [0, 1] every or no pixel passes
            raise InputError(f"--beta must be in [0, 1] (a heatmap threshold), got {self.beta!r}")
        if self.weights and self.detector == "canny":
            raise InputError(f"--weights {self.weights}: the canny detector has no weights "
                             "(they are for --detector learned or sold2)")
        if self.weights and not Path(self.weights).is_file():   # before any work (a study's cells)
            raise InputError(f"--weights {self.weights}: weights file not found")
        return self

    def detector_keywords(self) -> dict:
        """The keywords :func:`graphtrack.detect.make_detector` builds the detector with."""
        kw = {"weights": self.weights} if self.weights else {}
        if not self.turn and self.detector == "learned":
            kw["turn"] = False
        return kw


def check_observation(model: str) -> str:
    if model not in OBSERVATION_MODELS:
        raise InputError(f"--observation: unknown model {model!r} (choose from {', '.join(OBSERVATION_MODELS)})")
    return model
