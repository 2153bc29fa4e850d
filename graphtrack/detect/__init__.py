"""Shaft-edge and marker detection in undistorted pixels, and the method's pixel sets.

- :mod:`.base`: Detection / Observation contracts, OBSERVATION_MODELS;
- :mod:`.canny`: the Canny + Hough baseline (:mod:`.hough`: oriented Hough
  lines; :mod:`.line_refit`: their sub-pixel refit and segments);
  :func:`make_detector` builds any registered detector by name;
- :mod:`.association`: which candidate lines are the shaft's two edges;
- :mod:`.pixel_sets`: E_e and E_l; :mod:`.ransac`: sequential RANSAC / TLS;
- :mod:`.markers`: colour markers; :mod:`.observe`: Detection -> Observation;
- :mod:`.draw`: overlays.

Detector registry: ``DETECTORS`` maps a name to "module:Class"; the module is
imported only when that detector is asked for, so an optional detector whose
dependencies are missing never breaks the others. Add one with
:func:`register_detector` (or an entry in ``DETECTORS``).
"""
from __future__ import annotations

import importlib

from graphtrack.detect.association import Association, AssociationConfig, associate
from graphtrack.detect.base import OBSERVATION_MODELS, POLAR_MODELS, Detection, Detector, Observation, detect_raw
from graphtrack.detect.markers import MarkerConfig, detect_markers
from graphtrack.detect.observe import make_observation
from graphtrack.detect.pixel_sets import endpoint_set, endpoints_set, line_set
from graphtrack.detect.ransac import RansacConfig, best_line, fit_line_tls, sequential_ransac
from graphtrack.errors import InputError

#: name -> "module:Class"; the class is built as Class(**kwargs).
DETECTORS: dict[str, str] = {
    "canny": "graphtrack.detect.canny:CannyDetector",
    "learned": "graphtrack.detect.learned:LearnedDetector",
    "sold2": "graphtrack.detect.sold2:Sold2Detector",
}


def register_detector(name: str, target: str) -> None:
    """Register (or replace) detector ``name`` as "package.module:Class"."""
    if ":" not in target:
        raise ValueError(f"detector target must be 'module:Class', got '{target}'")
    DETECTORS[name] = target


def available_detectors() -> tuple[str, ...]:
    """Registered detector names (importability is checked only by make_detector)."""
    return tuple(DETECTORS)


def make_detector(name: str, **kwargs) -> Detector:
    """Build detector ``name`` with keyword options (e.g. ``make_detector("canny",
    votes=80)``). Unknown names and detectors whose module is not installed
    raise :class:`graphtrack.errors.InputError`."""
    if name not in DETECTORS:
        raise InputError(f"unknown detector '{name}' (choose from {', '.join(DETECTORS)})")
    module_name, _, attr = DETECTORS[name].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        raise InputError(f"detector '{name}' is not available: {e}") from None
    cls = getattr(module, attr, None)
    if cls is None:
        raise InputError(f"detector '{name}' is not available: {module_name} has no {attr}")
    return cls(**kwargs)


__all__ = [
    "Association", "AssociationConfig", "DETECTORS", "Detection", "Detector", "MarkerConfig",
    "OBSERVATION_MODELS", "Observation", "POLAR_MODELS", "RansacConfig", "associate",
    "available_detectors", "best_line", "detect_markers", "detect_raw", "endpoint_set", "endpoints_set",
    "fit_line_tls", "line_set", "make_detector", "make_observation", "register_detector",
    "sequential_ransac",
]
