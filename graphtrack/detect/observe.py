"""Build the estimator's Observation from a Detection, for each observation model.

Notation (:mod:`graphtrack.detect.base`): detected shaft edge i has endpoints
e^a_i, e^b_i (its segment) and line l_i = (rho_i, theta_i); H is the heatmap;
alpha (px) and beta the set radius and heatmap threshold; E_e, E_l the
endpoint and line sets of :mod:`graphtrack.detect.pixel_sets`.

====================================  ========================================
model                                 per detected edge i
====================================  ========================================
``canny``                             l_i = the detector's shaft line
``endpoints-polar``                   the line through e^a_i and e^b_i (the
                                      alpha = 0 limit of the sets)
``endpoint-intensities-polar``        best sequential-RANSAC line of
                                      E_e(e^a_i) U E_e(e^b_i), each sample
                                      spanning the two discs (an edge with
                                      fewer than 2 pixels in a disc is left
                                      out)
``line-intensities-polar``            best sequential-RANSAC line of
                                      E_l(e^a_i, e^b_i)
``endpoint-intensities``              the pixels E_e(e^a_i) U E_e(e^b_i)
``line-intensities``                  the pixels E_l(e^a_i, e^b_i)
====================================  ========================================

Polar models fill ``Observation.lines`` (k, 2), pixel models
``Observation.pixels`` (k arrays (m_i, 2)); ``edge_ids`` keeps, for each, the
predicted edge it belongs to (edge order is preserved). An edge whose set is
empty, or whose set holds too few pixels for a RANSAC line, is left out (with
its id), so k may shrink. A Detection without a heatmap (H = None) is treated
as H = 1 everywhere: the sets are then the full discs / capsules of radius
alpha around the endpoints / segment (clipped to x, y >= 0). Markers are the
detection's marker centroids when ``use_markers`` (else empty).

``max_pixels`` (default ``MAX_PIXELS`` = 250) caps each edge's set (pixel
models and the RANSAC input of the -polar ones) by keeping evenly spaced pixels
of it; why: docs/decisions/pixel-set-thinning.md.
"""
from __future__ import annotations

import numpy as np

from graphtrack.detect.base import OBSERVATION_MODELS, Detection, Observation
from graphtrack.detect.pixel_sets import ALPHA, BETA, carry_to_segment, endpoints_set, line_set
from graphtrack.detect.ransac import RansacConfig, best_line, seeded_rng
from graphtrack.geometry.image_scale import scale_lines, scale_points
from graphtrack.geometry.lines import line_through


def _ids(detection: Detection, k: int) -> np.ndarray:
    ids = np.asarray(getattr(detection, "edge_ids", np.zeros(0)), dtype=int).ravel()
    if len(ids) != k:  # a detector that did not label its edges: keep their order
        ids = np.arange(k, dtype=int)
    return ids


MAX_PIXELS = 250

#: models whose observation draws random numbers (the RANSAC line of each set), so
#: it depends on the run's seed
SEEDED_MODELS = ("endpoint-intensities-polar", "line-intensities-polar")


def _thin(points: np.ndarray, max_pixels: int | None) -> np.ndarray:
    """At most ``max_pixels`` evenly spaced rows of ``points`` (all when None/0)."""
    if not max_pixels or len(points) <= max_pixels:
        return points
    return points[np.linspace(0, len(points) - 1, max_pixels).round().astype(int)]


def make_observation(detection: Detection, model: str, alpha: float = ALPHA, beta: float = BETA,
                     use_markers: bool = True, rng=None,
                     ransac: RansacConfig | None = None, max_pixels: int | None = MAX_PIXELS) -> Observation:
    """The Observation of ``detection`` under ``model`` (one of OBSERVATION_MODELS).

    rng: numpy Generator or seed for RANSAC (None: seed 0, reproducible).
    """
    if model not in OBSERVATION_MODELS:
        raise ValueError(f"unknown observation model '{model}' (choose from {', '.join(OBSERVATION_MODELS)})")
    markers = np.asarray(detection.markers, float).reshape(-1, 2) if use_markers else np.zeros((0, 2))
    obs = Observation(model=model, markers=markers.copy())
    H = detection.heatmap

    if model == "canny":
        lines = np.asarray(detection.shaft_lines, float).reshape(-1, 2)
        ids = _ids(detection, len(lines))
        ok = np.all(np.isfinite(lines), axis=1)
        obs.lines, obs.edge_ids = lines[ok].copy(), ids[ok]
        return obs

    segs = np.asarray(detection.shaft_segments, float).reshape(-1, 4)
    ids = _ids(detection, len(segs))
    ok = np.all(np.isfinite(segs), axis=1)
    segs, ids = segs[ok], ids[ok]

    if model == "endpoints-polar":
        if len(segs):
            rho, theta = line_through(segs[:, :2], segs[:, 2:])
            good = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0
            obs.lines = np.stack([rho, theta], 1)[good]
            obs.edge_ids = ids[good]
        return obs

    endpoint = model.startswith("endpoint-")
    refined = np.asarray(getattr(detection, "refined", np.zeros(0)), bool).ravel()
    flagged = len(refined) == len(ok) and len(ok) > 0     # the detector says which sets are bands
    refined = refined[ok] if flagged else np.zeros(len(segs), bool)
    sets = [(endpoints_set if endpoint else line_set)(H, seg, alpha, beta) for seg in segs]
    sets = [_thin(carry_to_segment(pts, seg) if r else pts, max_pixels) for pts, seg, r in zip(sets, segs, refined)]

    if model.endswith("-polar"):
        gen = seeded_rng(rng)
        lines, kept = [], []
        for eid, pts, seg in zip(ids, sets, segs):
            # E_e: label each pixel by its endpoint disc, so that samples span the edge
            groups = None
            if endpoint:
                groups = (np.sum((pts - seg[:2]) ** 2, axis=1) > np.sum((pts - seg[2:4]) ** 2, axis=1)
                          ).astype(int)
                if min(np.sum(groups == 0), np.sum(groups == 1)) < 2:
                    continue  # one disc alone (a ~20 px blob) does not fix the edge's angle
            line, _ = best_line(pts, ransac, gen, groups)
            if line is not None:
                lines.append(line)
                kept.append(eid)
        obs.lines = np.array(lines, float).reshape(-1, 2)
        obs.edge_ids = np.array(kept, dtype=int)
        return obs

    keep = [i for i, p in enumerate(sets) if len(p) > 0]
    obs.pixels = [sets[i] for i in keep]
    obs.edge_ids = ids[keep] if keep else np.zeros(0, dtype=int)
    obs.bands = np.array([flagged and not refined[i] for i in keep], bool)
    return obs


def scale_observation(obs: Observation, s: float) -> Observation:
    """The same observation in the pixels of an image scaled by ``s``."""
    if s == 1.0:
        return obs
    return Observation(model=obs.model, lines=scale_lines(obs.lines, s),
                       pixels=[scale_points(p, s) for p in obs.pixels],
                       markers=scale_points(np.asarray(obs.markers, float).reshape(-1, 2), s),
                       edge_ids=np.asarray(obs.edge_ids).copy(), bands=np.asarray(obs.bands, bool).copy(),
                       shaft_end=_scale_end(obs.shaft_end, s))


def _scale_end(end: np.ndarray, s: float) -> np.ndarray:
    end = np.asarray(end, float).reshape(-1, 4).copy()
    end[:, :2] *= s
    return end


def scale_detection(det: Detection, s: float) -> Detection:
    """The detection's geometry in the pixels of an image scaled by ``s`` (the
    heatmap stays at the detector's resolution)."""
    if s == 1.0:
        return det

    def segs(a):
        return scale_points(np.asarray(a, float).reshape(-1, 2, 2), s).reshape(-1, 4)

    return Detection(segments=segs(det.segments), heatmap=det.heatmap, shaft_segments=segs(det.shaft_segments),
                     shaft_lines=scale_lines(det.shaft_lines, s),
                     markers=scale_points(np.asarray(det.markers, float).reshape(-1, 2), s),
                     ms=det.ms, edge_ids=np.asarray(det.edge_ids).copy(),
                     refined=np.asarray(det.refined, bool).copy())
