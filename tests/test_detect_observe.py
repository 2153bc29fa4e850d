"""Observation models built from a Detection, and the overlay helper."""
from __future__ import annotations

import numpy as np
import pytest

from graphtrack.detect import OBSERVATION_MODELS, POLAR_MODELS, Detection, make_observation
from graphtrack.detect.canny import CannyDetector
from graphtrack.detect.draw import YELLOW, draw_detection
from test_detect_canny import MARKER, assert_lines_close, shaft_scene, truth_lines


@pytest.fixture(scope="module")
def scene():
    img = shaft_scene(texture=10.0)
    return img, CannyDetector().detect(img, truth_lines())


@pytest.mark.parametrize("model", OBSERVATION_MODELS)
def test_every_model_output_kind(scene, model):
    _, det = scene
    obs = make_observation(det, model)
    assert obs.model == model
    assert obs.edge_ids.tolist() == [0, 1]
    assert len(obs.markers) == 1 and np.hypot(*(obs.markers[0] - MARKER)) < 0.5
    if model in POLAR_MODELS:
        assert obs.lines.shape == (2, 2) and obs.pixels == []
        assert_lines_close(obs.lines, truth_lines(), px=2.0, rad=0.02)
    else:
        assert len(obs.lines) == 0 and len(obs.pixels) == 2
        for pts, (rho, th), seg in zip(obs.pixels, truth_lines(), det.shaft_segments):
            assert pts.ndim == 2 and pts.shape[1] == 2 and len(pts) > 10
            # every pixel is an edge pixel (H >= beta) within alpha of the segment / endpoints
            assert np.all(det.heatmap[pts[:, 1].astype(int), pts[:, 0].astype(int)] >= 0.9)
            assert np.all(np.abs(np.cos(th) * pts[:, 0] + np.sin(th) * pts[:, 1] - rho) <= 10.0 + 1e-9)
            if model == "endpoint-intensities":
                da = np.hypot(*(pts - seg[:2]).T)
                db = np.hypot(*(pts - seg[2:]).T)
                assert np.all(np.minimum(da, db) <= 10.0 + 1e-9)
    assert obs.has_shaft and not obs.empty


def test_sets_grow_with_alpha(scene):
    _, det = scene
    small = make_observation(det, "line-intensities", alpha=3.0)
    big = make_observation(det, "line-intensities", alpha=10.0)
    assert all(len(a) <= len(b) for a, b in zip(small.pixels, big.pixels))


def test_markers_off_and_rng_reproducible(scene):
    _, det = scene
    a = make_observation(det, "line-intensities-polar", use_markers=False, rng=3)
    b = make_observation(det, "line-intensities-polar", use_markers=False, rng=np.random.default_rng(3))
    assert len(a.markers) == 0
    np.testing.assert_array_equal(a.lines, b.lines)


def test_hidden_edge_keeps_edge_id():
    seg = np.array([[0.0, 470.0, 620.0, 240.0]])
    from graphtrack.geometry.lines import line_through
    rho, th = line_through(seg[0, :2], seg[0, 2:])
    det = Detection(shaft_segments=seg, shaft_lines=np.array([[rho, th]]), edge_ids=np.array([1]))
    for model in OBSERVATION_MODELS:
        obs = make_observation(det, model)
        assert obs.edge_ids.tolist() == [1], model
        # no heatmap: H = 1 inside the sets (full discs / capsule: the RANSAC
        # line is only known to pass through them)
        if model in POLAR_MODELS:
            assert obs.lines.shape == (1, 2)
            drho = abs(obs.lines[0, 0] - rho)
            assert abs(obs.lines[0, 1] - th) < 0.04 and drho < 10.0, model
        else:
            assert len(obs.pixels) == 1 and len(obs.pixels[0]) > 100


@pytest.mark.parametrize("model", OBSERVATION_MODELS)
def test_empty_detection(model):
    obs = make_observation(Detection(), model)
    assert obs.empty and len(obs.edge_ids) == 0
    det = CannyDetector().detect(np.zeros((64, 64, 3), np.uint8))
    assert make_observation(det, model).empty


def test_unknown_model():
    with pytest.raises(ValueError):
        make_observation(Detection(), "nope")


def test_draw_detection(scene):
    img, det = scene
    out = draw_detection(img, det, make_observation(det, "line-intensities"))
    assert out.shape == img.shape and out.dtype == np.uint8
    assert out is not img and not np.array_equal(out, img)
    assert np.all(out == YELLOW, axis=2).sum() > 500      # thick shaft segments
    yellowish = (out[:, :, 0] < 120) & (out[:, :, 1] > 170) & (out[:, :, 2] > 170)
    assert yellowish[:, -50:].any()                      # full lines reach past the segments
    out2 = draw_detection(img[:, :, 0], det, make_observation(det, "line-intensities-polar"))
    assert out2.shape == img.shape
    draw_detection(np.zeros((8, 8, 3), np.uint8), Detection())


def test_scale_observation_maps_lines_and_points_consistently():
    from graphtrack.detect.base import Observation
    from graphtrack.detect.observe import scale_observation
    from graphtrack.geometry.lines import line_through, pixel_residual

    rng = np.random.default_rng(0)
    a, b = np.array([12.3, 40.1]), np.array([301.7, 222.9])
    rho, theta = line_through(a, b)
    t = rng.uniform(0, 1, (20, 1))
    pts = a + t * (b - a)
    obs = Observation("line-intensities", lines=np.array([[rho, theta]]), pixels=[pts], markers=pts[:3])
    big = scale_observation(obs, 2.0)
    # points on the line stay on the scaled line; a scaled-image pixel (x+0.5)*2-0.5
    assert np.abs(pixel_residual(big.pixels[0], big.lines[0, 0], big.lines[0, 1])).max() < 1e-9
    np.testing.assert_allclose(big.markers, (pts[:3] + 0.5) * 2 - 0.5)
    back = scale_observation(big, 0.5)
    np.testing.assert_allclose(back.lines, obs.lines, atol=1e-12)


def test_endpoint_polar_needs_both_endpoint_discs():
    """A heatmap that fades before one end leaves one endpoint disc empty: the edge
    is left out of endpoint-intensities-polar (one ~20 px blob fixes no angle), but
    its pixels still count for endpoint-intensities."""
    seg = np.array([[100.0, 400.0, 500.0, 150.0]])
    from graphtrack.geometry.lines import line_through
    rho, th = line_through(seg[0, :2], seg[0, 2:])
    H = np.zeros((480, 640), np.float32)
    yy, xx = np.mgrid[0:480, 0:640]
    near = np.abs(np.cos(th) * xx + np.sin(th) * yy - rho) <= 2.0
    H[near & (xx < 300)] = 1.0                      # the line only near the first endpoint
    det = Detection(shaft_segments=seg, shaft_lines=np.array([[rho, th]]), heatmap=H,
                    edge_ids=np.array([0]))
    assert len(make_observation(det, "endpoint-intensities-polar").lines) == 0
    assert len(make_observation(det, "endpoint-intensities").pixels) == 1
    H[near] = 1.0                                   # both ends: the edge's line
    line = make_observation(det, "endpoint-intensities-polar").lines
    assert len(line) == 1 and abs(line[0, 1] - th) < 0.02


@pytest.mark.parametrize("model", ["line-intensities", "endpoint-intensities", "line-intensities-polar"])
def test_sets_of_refined_edges_are_carried_onto_the_refined_segment(model):
    """A heatmap band 2.5 px off the segment (a coarse heatmap's offset): the sets of an
    edge the refinement moved (Detection.refined) lie on the segment's line, those of
    an edge it did not keep the heatmap's offset."""
    from graphtrack.geometry.lines import line_through, pixel_residual

    seg = np.array([[100.0, 400.0, 500.0, 150.0]])
    rho, th = line_through(seg[0, :2], seg[0, 2:])
    H = np.zeros((480, 640), np.float32)
    yy, xx = np.mgrid[0:480, 0:640]
    H[np.abs(np.cos(th) * xx + np.sin(th) * yy - rho - 2.5) <= 1.5] = 1.0
    base = dict(shaft_segments=seg, shaft_lines=np.array([[rho, th]]), heatmap=H, edge_ids=np.array([0]))

    def offset(det):
        obs = make_observation(det, model)
        if obs.lines.size:
            return obs.lines[0, 0] - rho if abs(obs.lines[0, 1] - th) < 0.1 else rho - obs.lines[0, 0]
        return float(np.mean(pixel_residual(obs.pixels[0], rho, th)))

    assert abs(offset(Detection(**base)) - 2.5) < 0.3
    assert abs(offset(Detection(**base, refined=np.array([True])))) < 0.3


def test_bands_are_the_sets_of_edges_a_flagging_detector_did_not_refine():
    """Observation.bands follows Detection.refined per pixel set (False where the edge
    was refined, True where not), is empty-handed (all False) for a detector that sets
    no flags (the Canny detector), and survives scale_observation."""
    from graphtrack.detect.observe import scale_observation

    segs = np.array([[100.0, 400.0, 500.0, 150.0], [120.0, 440.0, 520.0, 190.0]])
    H = np.zeros((480, 640), np.float32)
    yy, xx = np.mgrid[0:480, 0:640]
    for a, b in ((segs[0, :2], segs[0, 2:]), (segs[1, :2], segs[1, 2:])):
        d = (b - a) / np.linalg.norm(b - a)
        H[np.abs(-d[1] * (xx - a[0]) + d[0] * (yy - a[1])) <= 1.0] = 1.0
    base = dict(shaft_segments=segs, heatmap=H, edge_ids=np.array([0, 1]))
    for model in ("line-intensities", "endpoint-intensities"):
        flagged = make_observation(Detection(**base, refined=np.array([True, False])), model)
        assert flagged.bands.tolist() == [False, True]
        assert scale_observation(flagged, 0.5).bands.tolist() == [False, True]
        assert make_observation(Detection(**base), model).bands.tolist() == [False, False]
    # an empty set and a NaN segment are dropped with their flags: the bands stay aligned
    three = np.vstack([[600.0, 10.0, 630.0, 20.0], segs[1], [np.nan] * 4])   # the first has no heatmap
    det = Detection(shaft_segments=three, heatmap=H, edge_ids=np.array([0, 1, 2]),
                    refined=np.array([True, False, True]))
    obs = make_observation(det, "line-intensities")
    assert len(obs.pixels) == 1 and obs.bands.tolist() == [True] and obs.edge_ids.tolist() == [1]

