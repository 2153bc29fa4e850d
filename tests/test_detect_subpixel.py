"""Sub-pixel edge refinement against edges rendered from a known line."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from graphtrack.detect.subpixel import SubpixelConfig, refine_segment, refine_segments, edge_gradient
from graphtrack.geometry.lines import line_difference, line_through


def render_edge(rho: float, theta: float, shape=(200, 300), inside=40.0, outside=190.0, blur=0.8,
                ss: int = 8) -> np.ndarray:
    """Grey image: ``inside`` where cos t x + sin t y < rho, ``outside`` beyond, each
    pixel the mean of ss x ss sub-samples of its unit square (pixel centres at
    integers), then a Gaussian blur of ``blur`` px (a camera's point spread)."""
    h, w = shape
    o = (np.arange(ss) + 0.5) / ss - 0.5
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    cover = np.zeros(shape)
    for dy in o:
        for dx in o:
            cover += (np.cos(theta) * (xs + dx) + np.sin(theta) * (ys + dy) < rho)
    img = outside + (inside - outside) * cover / ss ** 2
    img = img.astype(np.float32)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _segment_on(rho, theta, s0, s1, shift=0.0, turn=0.0):
    """Endpoints at arc lengths s0, s1 along the line (rho + shift, theta + turn)."""
    t = theta + turn
    n, d = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
    p0 = (rho + shift) * n
    return np.concatenate([p0 + s0 * d, p0 + s1 * d])


@pytest.mark.parametrize("dark_inside", [True, False])
def test_refined_segment_lies_on_the_rendered_edge(dark_inside):
    rho, theta = 150.0, 0.35
    img = render_edge(rho, theta, inside=40 if dark_inside else 190, outside=190 if dark_inside else 40)
    seg = _segment_on(rho, theta, -60.0, 90.0, shift=1.6, turn=0.008)     # a 1/4-scale detection's error
    gx, gy = edge_gradient(img, (0, 0, img.shape[1], img.shape[0]), 1.0)
    out = refine_segment(gx, gy, seg)
    assert out is not None
    r, t = line_through(out[:2][None], out[2:][None])
    dr, dt = line_difference(r[0], t[0], rho, theta)
    assert abs(dr) < 0.05 and abs(dt) < 5e-4
    # the refined endpoints are the detected ones moved onto the edge, not along it
    for k in (0, 2):
        along = np.array([-np.sin(theta), np.cos(theta)])
        assert abs(along @ (out[k:k + 2] - seg[k:k + 2])) < 0.1


def test_refine_segments_works_in_a_box_and_keeps_what_the_image_does_not_support():
    rho, theta = 150.0, 0.35
    img = cv2.cvtColor(render_edge(rho, theta), cv2.COLOR_GRAY2BGR)
    good = _segment_on(rho, theta, -60.0, 90.0, shift=-1.2)
    far = _segment_on(rho + 40.0, theta, -60.0, 90.0)            # no edge within the search window
    nan = np.full(4, np.nan)
    out = refine_segments(img, np.stack([good, far, nan]))
    r, t = line_through(out[:1, :2], out[:1, 2:])
    assert abs(line_difference(r[0], t[0], rho, theta)[0]) < 0.05
    np.testing.assert_array_equal(out[1], far)
    assert np.all(np.isnan(out[2]))


def test_no_refinement_on_a_flat_image_or_a_short_segment():
    flat = np.full((120, 160), 100, np.uint8)
    seg = np.array([20.0, 20.0, 140.0, 100.0])
    gx, gy = edge_gradient(flat, (0, 0, 160, 120), 1.0)
    assert refine_segment(gx, gy, seg) is None
    img = render_edge(80.0, 0.3, shape=(120, 160))
    gx, gy = edge_gradient(img, (0, 0, 160, 120), 1.0)
    assert refine_segment(gx, gy, _segment_on(80.0, 0.3, 0.0, 20.0)) is None     # under 2 x 6 + 8 x 4 px


@pytest.mark.parametrize("theta", [0.0, np.pi / 2])
def test_axis_aligned_edges_have_no_grid_dependent_bias(theta):
    # a 3-sample parabola on bilinear samples was up to 0.13 px off here, cycling
    # with the edge's position inside a pixel
    for frac in np.arange(8) / 8:
        rho = 120.0 + frac
        img = render_edge(rho, theta)
        gx, gy = edge_gradient(img, (0, 0, img.shape[1], img.shape[0]), 1.0)
        s0, s1 = (20.0, 160.0) if theta == 0.0 else (-280.0, -140.0)     # inside the image
        out = refine_segment(gx, gy, _segment_on(rho, theta, s0, s1, shift=1.0))
        r, t = line_through(out[:2][None], out[2:][None])
        assert abs(line_difference(r[0], t[0], rho, theta)[0]) < 0.05


def _two_segments(rho, theta, width, shift=0.0):
    """The shaft's two edges: rho (+ shift) and rho - width, the shaft between them."""
    return np.stack([_segment_on(rho, theta, -60.0, 90.0, shift=shift),
                     _segment_on(rho - width, theta, -60.0, 90.0)])


def _edge_error(seg, rho, theta):
    r, t = line_through(seg[None, :2], seg[None, 2:])
    return abs(line_difference(r[0], t[0], rho, theta)[0])


@pytest.mark.parametrize("case, gap", [("black border", 2.5), ("second step", 4.0), ("bright stripe", 4.0)])
def test_a_competing_edge_inside_the_window_never_makes_the_edge_worse(case, gap):
    # the shaft (dark, 40) lies below both edges: cos t x + sin t y < rho; background 150.
    # A competing edge ``gap`` px away, inside the +-3 px window of a detection 1.5 px
    # off. (Closer, two steps merge under the camera's and the gradient's blur into one
    # peak and the stronger wins: a limit documented in the module.)
    rho, theta, width = 150.0, 0.35, 60.0
    shaft = render_edge(rho, theta, inside=1.0, outside=0.0, blur=0.0).astype(float)
    shaft *= 1.0 - render_edge(rho - width, theta, inside=1.0, outside=0.0, blur=0.0)
    img = 150.0 - 110.0 * shaft
    beyond = render_edge(rho + gap, theta, inside=0.0, outside=1.0, blur=0.0).astype(float)
    if case == "black border":          # the undistortion's empty border outside the edge
        img = img * (1.0 - beyond)
    elif case == "second step":         # 40 | 80 | 190: a stronger step outside
        img = np.where(shaft > 0.5, 40.0, np.where(beyond > 0.5, 190.0, 80.0))
    else:                               # a bright 2 px stripe on the shaft inside the edge
        stripe = render_edge(rho - gap, theta, inside=0.0, outside=1.0, blur=0.0).astype(float)
        stripe *= render_edge(rho - gap + 2.0, theta, inside=1.0, outside=0.0, blur=0.0)
        img = img + 120.0 * stripe
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.8).astype(np.uint8)
    for shift in (0.0, 1.5, -1.5):
        segs = _two_segments(rho, theta, width, shift)
        out = refine_segments(img, segs)
        assert _edge_error(out[0], rho, theta) <= max(_edge_error(segs[0], rho, theta), 0.1) + 1e-9
        assert _edge_error(out[1], rho - width, theta) < 0.1      # the other edge is clean


def test_noisy_low_contrast_edges_are_refined_and_pure_noise_is_left_alone():
    rng = np.random.default_rng(5)
    rho, theta = 150.0, 0.35
    for shift in (-2.0, -1.0, 1.0, 2.0):
        img = render_edge(rho, theta, inside=120, outside=140).astype(float)
        img = np.clip(img + rng.normal(0, 3.0, img.shape), 0, 255).astype(np.uint8)
        gx, gy = edge_gradient(img, (0, 0, img.shape[1], img.shape[0]), 1.0)
        out = refine_segment(gx, gy, _segment_on(rho, theta, -60.0, 90.0, shift=shift))
        assert out is not None and _edge_error(out, rho, theta) < 0.15
    noise = np.clip(128 + rng.normal(0, 3.0, (200, 300)), 0, 255).astype(np.uint8)
    gx, gy = edge_gradient(noise, (0, 0, 300, 200), 1.0)
    assert refine_segment(gx, gy, _segment_on(rho, theta, -60.0, 90.0)) is None


def test_a_parallel_edge_outside_the_search_window_does_not_pull():
    rho, theta = 150.0, 0.35
    a = render_edge(rho, theta).astype(float)
    stripe = render_edge(rho - 8.0, theta, inside=0, outside=60).astype(float)   # a specular stripe 8 px inside
    img = np.clip(a + 60 - stripe, 0, 255).astype(np.uint8)
    gx, gy = edge_gradient(img, (0, 0, img.shape[1], img.shape[0]), 1.0)
    out = refine_segment(gx, gy, _segment_on(rho, theta, -60.0, 90.0, shift=-1.5),
                         config=SubpixelConfig(search=3.0))
    r, t = line_through(out[:2][None], out[2:][None])
    assert abs(line_difference(r[0], t[0], rho, theta)[0]) < 0.1


def test_refinement_on_the_raw_frame_through_the_distortion_finds_the_undistorted_edge():
    # oracle: a straight edge in undistorted pixels, drawn into the RAW image through the
    # plumb-bob model (each raw pixel takes the undistorted image at its undistorted
    # position, OpenCV's undistortPoints), so the raw edge is curved
    from graphtrack.geometry.camera import Camera

    K = np.array([[250.0, 0, 150], [0, 250.0, 100], [0, 0, 1]])
    cam = Camera(K, np.array([-0.28, 0.09, 0.0005, -0.0004, 0.0]), 200, 300)
    rho, theta = 250.0, 0.2
    ss = 4                                               # the undistorted edge, 4x supersampled
    fine = render_edge(rho * ss + (ss - 1) / 2 * (np.cos(theta) + np.sin(theta)), theta,
                       shape=(200 * ss, 300 * ss), blur=0.8 * ss, ss=2)
    ys, xs = np.mgrid[0:200, 0:300].astype(np.float32)
    und = cam.undistort_pixels(np.stack([xs.ravel(), ys.ravel()], 1)).reshape(200, 300, 2)
    mx, my = ((und + 0.5) * ss - 0.5).astype(np.float32).transpose(2, 0, 1)
    raw = cv2.remap(fine, mx, my, cv2.INTER_AREA)
    seg = _segment_on(rho, theta, -20.0, 120.0, shift=1.5, turn=0.008)
    assert np.abs(cam.distort_pixels(seg.reshape(2, 2)) - seg.reshape(2, 2)).max() > 4.0  # it matters
    out = refine_segments(raw, seg[None], camera=cam)[0]
    r, t = line_through(out[:2][None], out[2:][None])
    dr, dt = line_difference(r[0], t[0], rho, theta)
    assert abs(dr) < 0.1 and abs(dt) < 1e-3
    # without the camera the raw frame's curved edge is refined as if straight: worse
    plain = refine_segments(raw, seg[None])[0]
    r2, t2 = line_through(plain[:2][None], plain[2:][None])
    assert abs(line_difference(r2[0], t2[0], rho, theta)[0]) > abs(dr)


def _shaft_image(rho, theta, width, blur):
    """A dark (40) shaft between the edges rho and rho - width on a 150 background, blurred."""
    shaft = render_edge(rho, theta, inside=1.0, outside=0.0, blur=0.0).astype(float)
    shaft *= 1.0 - render_edge(rho - width, theta, inside=1.0, outside=0.0, blur=0.0)
    return cv2.GaussianBlur((150.0 - 110.0 * shaft).astype(np.float32), (0, 0), blur).astype(np.uint8)


def test_an_edge_inside_the_shaft_beyond_the_window_is_found_by_a_wider_search():
    # the net's band lies outside the silhouette, at times by more than the +-3 px window
    # (a blurred or low-contrast edge); the rows' peaks then pile up on the window's inner
    # end, and the search is repeated reaching into the shaft
    rho, theta, width = 150.0, 0.35, 60.0
    img = _shaft_image(rho, theta, width, 1.5)
    for shift in (4.5, 6.5):                # outside the shaft (edge 0's outside: larger rho)
        out = refine_segments(img, _two_segments(rho, theta, width, shift))
        assert _edge_error(out[0], rho, theta) < 0.1
        assert _edge_error(out[1], rho - width, theta) < 0.1


def test_an_edge_outside_the_shaft_beyond_the_window_is_not_searched_for():
    # outwards lies the background, where a stronger parallel edge merges with the
    # silhouette's under blur (the module's known limit): no wider search there
    rho, theta, width = 150.0, 0.35, 60.0
    img = _shaft_image(rho, theta, width, 0.8)
    segs = _two_segments(rho, theta, width, -4.5)      # 4.5 px inside the shaft
    out = refine_segments(img, segs)
    np.testing.assert_array_equal(out[0], segs[0])
