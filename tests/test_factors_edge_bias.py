"""The edge-bias state: its factors' Jacobians against central differences, the
Gauss-Markov chain against hand-computed values, the batch marginals against
gtsam.Marginals, and what it is for: a persistent edge offset no longer drags E."""
import gtsam
import numpy as np
import pytest

from factors.edge_bias import (BIAS_DIM, END_OFFSET, SLOPE_SCALE, BiasTransitionError, bias_coefficients, bias_key,
                               bias_sigmas, bias_transition_factor, limb_bias, reference_direction,
                               transition)
from factors.limb import LimbPairing
from factors.line_parameter import LineParameterError
from factors.shaft_pixels import ShaftPixelsError, shaft_pixels_factor
from graphtrack.sim.synthetic import make_scene, sequence
from graphtrack.detect.base import Observation
from graphtrack.estimate import make_estimator
from graphtrack.io.frame import Frame
from graphtrack.io.context import TrackingContext
from graphtrack.estimate.graph import left_error
from graphtrack.geometry.cylinder import ShaftAxis, limb_line_coefficients, line_matrix
from graphtrack.robot.features import base_features

#: (sigma_rho px, sigma_theta rad) of a detected line in these tests
LINE_SIGMAS = (3.0, 0.01)
SCENE = make_scene()


@pytest.fixture(scope="module")
def scene():
    robot, cam, E0, fr = sequence(2, seed=3, scene=SCENE, outliers=0.2, pixel_noise=2.0, marker_noise=2.0)
    f = fr[1]
    F = base_features(robot, f.q)
    axis = ShaftAxis.make(F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0])
    return robot, cam, E0, f, axis


def test_bias_coefficients_by_hand():
    """Pixels on the line y = 2 x: c = (1, t / 100), t along the line from the centroid,
    pointing down the image (+y) whatever the pixels' order."""
    t = np.array([-50.0, 0.0, 150.0])
    u = np.array([1.0, 2.0]) / np.sqrt(5.0)
    p = np.array([10.0, 20.0]) + t[:, None] * u
    for q, tt in ((p, t), (p[::-1], t[::-1])):
        C = bias_coefficients(q)
        assert np.allclose(C, np.stack([np.ones(3), (tt - t.mean()) / SLOPE_SCALE], 1))
    flat = np.array([[5.0, 3.0], [1.0, 3.0], [9.0, 3.0]])       # horizontal: +x
    assert np.allclose(bias_coefficients(flat)[:, 1], [0.0, -0.04, 0.04])
    # a reference direction orients every set the same way, also either side of horizontal
    for tilt in (+0.005, -0.005):
        x = np.array([-150.0, 150.0])
        C = bias_coefficients(np.stack([x, 100 + tilt * x], 1), direction=np.array([-1.0, 0.0]))
        assert C[0, 1] > 0 > C[1, 1]
    assert bias_coefficients(np.zeros((0, 2))).shape == (0, 2)


def test_reference_direction_by_hand():
    """The axis through (0, 0, 0.1) m along +x, seen through E = I with fx = 800:
    image direction +x; an axis behind the camera has none."""
    K = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    d = reference_direction(np.eye(4), np.array([0.0, 0.0, 0.1]), np.array([1.0, 0.0, 0.0]), K)
    assert np.allclose(d, [1.0, 0.0])
    d = reference_direction(np.eye(4), np.array([0.0, 0.0, 0.1]), np.array([0.0, -0.6, 0.8]), K)
    assert d[0] == pytest.approx(0.0, abs=1e-12) and d[1] < 0
    assert reference_direction(np.eye(4), np.array([0.0, 0.0, -0.1]), np.array([1.0, 0, 0]), K) is None


def test_lateral_and_width_terms_by_hand(scene):
    """The two limbs' line normals point opposite ways, so moving every pixel of both
    edges by +d along limb 0's normal (a lateral shift) changes limb 0's residuals by
    +d and limb 1's by -d: limb_bias gives (w + l, w - l) on limbs (0, 1)."""
    robot, cam, E0, f, axis = scene
    L = limb_line_coefficients(f.E_true, axis, line_matrix(cam.K), False)[0]
    n = L[:, :2] / np.hypot(L[:, 0], L[:, 1])[:, None]
    assert n[0] @ n[1] < -0.99
    b = np.array([0.5, 0.2, 0.1, -0.3, 0.9])     # the end offset (last) is no limb's
    assert np.allclose(limb_bias(b, 0), [0.6, -0.1]) and np.allclose(limb_bias(b, 1), [-0.4, -0.5])


def _central_differences(fn, pose, b: np.ndarray, h: float = 1e-7, hb: float = 1e-5) -> np.ndarray:
    """[de/dxi, de/db] of fn.evaluate(E, jacobian, b) by central differences:
    Pose3.retract(+-h e_k) for E, b +- hb e_k for the bias."""
    E = pose.matrix()
    e = fn.evaluate(E, False, b)[0]
    Jn = np.zeros((len(e), 6 + len(b)))
    for k in range(6):
        x = np.zeros(6)
        x[k] = h
        Jn[:, k] = (fn.evaluate(pose.retract(x).matrix(), False, b)[0]
                    - fn.evaluate(pose.retract(-x).matrix(), False, b)[0]) / (2 * h)
    for k in range(len(b)):
        d = np.zeros(len(b))
        d[k] = hb
        Jn[:, 6 + k] = (fn.evaluate(E, False, b + d)[0] - fn.evaluate(E, False, b - d)[0]) / (2 * hb)
    return Jn


@pytest.mark.parametrize("kernel", ["none", "huber", "cauchy"])
def test_biased_pixels_jacobians(scene, kernel):
    """[de/dxi, de/db] against central differences (Pose3.retract for E, b + h e_k);
    at b = 0 the residual is the unbiased factor's; b shifts each pixel's residual by
    -(offset_i + slope_i t / 100) / sigma of its own limb i."""
    robot, cam, E0, f, axis = scene
    pairing = LimbPairing()
    fns = [ShaftPixelsError(px, axis, cam.K, 1.5, kernel, pairing, bias=True) for px in f.pixels[:2]]
    plain = ShaftPixelsError(f.pixels[0], axis, cam.K, 1.5, kernel)
    b = np.array([0.7, -0.4, -1.1, 0.3, 0.8])
    for E in (f.E_true, E0):
        pose = gtsam.Pose3(E)
        for fn in fns:
            e, J = fn.evaluate(E, True, b)
            assert J.shape == (len(e), 6 + BIAS_DIM)
            assert np.all(J[:, 6 + END_OFFSET] == 0)      # the end offset is the shaft end's
            Jn = _central_differences(fn, pose, b)
            tol = 2e-6 if kernel == "huber" else 1e-6
            assert np.max(np.abs(J - Jn)) <= tol * np.max(np.abs(Jn))
    e0 = fns[0].evaluate(E0, False, np.zeros(BIAS_DIM))[0]
    assert np.allclose(e0, plain.evaluate(E0, False)[0])
    if kernel == "none":
        fn = fns[0]
        fn.evaluate(E0, False)
        sgn = 1.0 if fn.limb == 0 else -1.0
        lateral = np.array([2.0, 0.5, 0.0, 0.0, 0.0])
        width = np.array([0.0, 0.0, 2.0, 0.5, 0.0])
        expect = e0 - (2.0 + 0.5 * fn.C[:, 1]) / 1.5
        assert np.allclose(fn.evaluate(E0, False, width)[0], expect)
        assert np.allclose(fn.evaluate(E0, False, lateral)[0], e0 - sgn * (2.0 + 0.5 * fn.C[:, 1]) / 1.5)


def test_gtsam_wrapper_has_both_keys(scene):
    robot, cam, E0, f, axis = scene
    x, b = gtsam.symbol("x", 0), bias_key(0)
    fac = shaft_pixels_factor(x, f.pixels[0], axis, cam.K, 1.5, "cauchy", bias_key=b)
    assert list(fac.keys()) == [x, b]
    v = gtsam.Values()
    v.insert(x, gtsam.Pose3(E0))
    v.insert(b, np.zeros(BIAS_DIM))
    gf = fac.linearize(v)
    assert gf.jacobian()[0].shape == (len(f.pixels[0]), 6 + BIAS_DIM)


def test_transition_by_hand():
    """phi = exp(-dt / tau); e = (b_k - phi b_{k-1}) / (sigma sqrt(1 - phi^2)), constant Jacobians."""
    sig = bias_sigmas(1.0, 0.5, 0.3, 0.2, 0.7)
    assert np.allclose(sig, [1.0, 0.5, 0.3, 0.2, 0.7])
    phi = transition(1 / 30, 2.0)
    assert phi == pytest.approx(np.exp(-1 / 60))
    assert transition(0.1, 0.0) == 0.0          # independent in every frame
    assert transition(0.1, np.inf) == 1.0       # constant
    fn = BiasTransitionError(phi, sig)
    a, c = np.array([1.0, 2.0, -1.0, 0.0, 0.4]), np.array([1.1, 1.9, -0.5, 0.2, 0.3])
    q = sig * np.sqrt(1 - phi ** 2)
    assert np.allclose(fn.evaluate(a, c), (c - phi * a) / q)
    v = gtsam.Values()
    v.insert(bias_key(3), a)
    v.insert(bias_key(4), c)
    gf = bias_transition_factor(3, 4, phi, sig).linearize(v)
    A = gf.jacobian()[0]
    n = BIAS_DIM
    assert np.allclose(A[:, :n], -phi * np.diag(1 / q)) and np.allclose(A[:, n:], np.diag(1 / q))


@pytest.mark.parametrize("every", [1, 5])
def test_batch_marginals_with_bias_match_gtsam(every):
    """The batch's O(n) block-tridiagonal marginals over blocks of frames (E_k ..., b_j)
    equal gtsam.Marginals: one bias per frame, and one per 5 frames with a partial last
    block (23 frames) and a frame without detections."""
    robot, cam, E0, frames = sequence(23, seed=5, scene=SCENE, walk_sigma=(2.5e-5, 1e-4), pixel_noise=1.5,
                                      marker_noise=2.0, pixels_per_edge=40)
    est = make_estimator("batch", TrackingContext(robot, cam, E0), edge_bias=True, edge_bias_every=every)
    for f in frames:
        obs = (Observation("line-intensities") if f.index == 7
               else Observation("line-intensities", pixels=f.pixels, markers=f.markers))
        est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]), obs)
    est.finish()
    graph, values = est.build()
    from graphtrack.estimate.lm import levenberg_marquardt

    result = levenberg_marquardt(graph, values, 30, 1e-8).values
    ours = est._chain_marginals(graph, result, len(frames))
    ref = gtsam.Marginals(graph, result)
    assert sum(chr(gtsam.Symbol(k).chr()) == "b" for k in values.keys()) == (len(frames) + every - 1) // every
    for k in (0, 7, 22):
        C = ref.marginalCovariance(gtsam.symbol("x", k))
        assert np.allclose(ours[k], C, rtol=1e-6, atol=1e-14)


def _biased_frames(robot, cam, E0, frames, offset, slope):
    """Move every pixel set off its true limb i by offset_i + slope_i t / 100 px along
    limb i's own normal (limb_line_coefficients orientation, into the shaft image), t along the
    edge oriented by the reference direction at E0: in every frame the same bias."""
    out = []
    for f in frames:
        F = base_features(robot, f.q)
        axis = ShaftAxis.make(F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0])
        L = limb_line_coefficients(f.E_true, axis, line_matrix(cam.K), False)[0]
        n = L[:, :2] / np.hypot(L[:, 0], L[:, 1])[:, None]
        direction = reference_direction(E0, F.shaft_p0[0], F.shaft_d[0], cam.K)
        sets = []
        for px in f.pixels:
            d = (np.hstack([px, np.ones((len(px), 1))]) @ L.T) / np.hypot(L[:, 0], L[:, 1])
            i = int(np.argmin(np.median(np.abs(d), axis=0)))
            t = bias_coefficients(px, direction)[:, 1]
            sets.append(px + (offset[i] + slope[i] * t)[:, None] * n[i])
        out.append(sets)
    return out


@pytest.mark.slow
def test_persistent_edge_offset_no_longer_drags_the_batch():
    """Both edge sets 1.5 px off their limbs the same way in the image (+1.5 px along
    limb 0's inward normal, -1.5 px along limb 1's: a lateral shift, l = 1.5) plus a
    width slope (both 1 px per 100 px inwards: w_s = 1), the same in every frame:
    with the bias state the batch's error is well below the error without it (the
    markers then carry the shift)."""
    robot, cam, E0, frames = sequence(120, seed=2, scene=SCENE, walk_sigma=(2.5e-5, 1e-4), pixel_noise=1.0,
                                      marker_noise=1.0, pixels_per_edge=80)
    shifted = _biased_frames(robot, cam, E0, frames, offset=(1.5, -1.5), slope=(1.0, 1.0))
    obs = [Observation("line-intensities", pixels=px, markers=f.markers) for f, px in zip(frames, shifted)]
    errs = _batch_errors_with_and_without_bias(robot, cam, E0, frames, obs)
    assert errs[True] < 0.6 * errs[False], errs


def _batch_errors_with_and_without_bias(robot, cam, E0, frames, observations) -> dict:
    """Mean translation error (m) of the batch over ``frames`` fed ``observations``,
    without (False) and with (True) the edge-bias state."""
    errs = {}
    for on in (False, True):
        est = make_estimator("batch", TrackingContext(robot, cam, E0), edge_bias=on, covariance=False)
        for f, ob in zip(frames, observations):
            est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]), ob)
        out = est.finish()
        e = np.array([left_error(f.E_true, x.E) for f, x in zip(frames, out)])
        errs[on] = np.linalg.norm(e[:, :3], axis=1).mean()
    return errs


@pytest.mark.parametrize("E_name", ["true", "prior"])
def test_biased_line_parameter_jacobians(scene, E_name):
    """The line-parameter factor with the bias state: [dr/dxi, dr/db] against central
    differences; at b = 0 the residual is the unbiased factor's."""
    robot, cam, E0, f, axis = scene
    E = f.E_true if E_name == "true" else E0
    pose = gtsam.Pose3(E)
    direction = reference_direction(E0, axis.p0, axis.d, cam.K)
    pairing = LimbPairing()
    fns = [LineParameterError(f.lines[i], axis, cam.K, *LINE_SIGMAS, pairing=pairing, bias=True,
                              direction=direction)
           for i in range(2)]
    plain = [LineParameterError(f.lines[i], axis, cam.K, *LINE_SIGMAS, pairing=LimbPairing()) for i in range(2)]
    b = np.array([0.7, -0.4, -1.1, 0.3, 0.8])
    for fn, pl in zip(fns, plain):
        r, J = fn.evaluate(E, True, b)
        assert J.shape == (2, 6 + BIAS_DIM)
        Jn = _central_differences(fn, pose, b)
        for row in range(2):
            assert np.max(np.abs(J[row] - Jn[row])) <= 1e-6 * np.max(np.abs(Jn[row]))
        assert np.allclose(fn.evaluate(E, False, np.zeros(BIAS_DIM))[0], pl.evaluate(E, False)[0], atol=1e-9)


def _moved_line(L: np.ndarray, offset: float, slope: float, direction: np.ndarray, c: np.ndarray):
    """(rho, theta) of the line L = (A, B, C) moved by ``offset`` px along its normal
    (A, B) (into the shaft image for limb_line_coefficients' orientation) at the foot of the
    point c, and turned by ``slope`` px per 100 px along ``direction``."""
    n = L[:2] / np.hypot(*L[:2])
    d0 = L[2] / np.hypot(*L[:2])                         # signed distance n.x + d0
    foot = c - (n @ c + d0) * n
    u = np.array([-n[1], n[0]])
    u = u if u @ direction >= 0 else -u
    p = np.array([foot + t * u + (offset + slope * t / SLOPE_SCALE) * n for t in (-200.0, 200.0)])
    e = p[1] - p[0]
    nd = np.array([-e[1], e[0]]) / np.hypot(*e)
    return np.array([nd @ p[0], np.arctan2(nd[1], nd[0])])


def test_biased_line_matches_a_moved_limb(scene):
    """Oracle by construction: a detected line made by moving the true limb i by
    offset o (into the shaft image) at the principal point's foot and turning it by
    slope s px per 100 px along the reference direction has zero residual at E_true
    with the b that gives limb i (o, s), and not at b = 0. (To second order in the
    slope k = s / 100: the factor anchors the offset at the principal point's foot
    on the detected line and turns along the detected line's direction, this
    construction at the foot on the limb and along the limb: 1e-3 px, 1e-5 rad,
    against effects of ~1 px and ~1e-2 rad.)"""
    from factors.line_parameter import LineParameterError

    robot, cam, E0, f, axis = scene
    L = limb_line_coefficients(f.E_true, axis, line_matrix(cam.K), False)[0]
    direction = reference_direction(E0, axis.p0, axis.d, cam.K)
    b = np.array([0.4, -0.8, 1.5, 0.6, 0.0])           # (l, l_s, w, w_s, e)
    for i in range(2):
        o, s = limb_bias(b, i)
        line = _moved_line(L[i], o, s, direction, cam.K[:2, 2])
        fn = LineParameterError(line, axis, cam.K, *LINE_SIGMAS, bias=True, direction=direction)
        r, _ = fn.evaluate(f.E_true, False, b)
        assert fn.limb == i
        assert abs(r[0]) < 1e-3 and abs(r[1]) < 1e-5
        r0, _ = fn.evaluate(f.E_true, False, np.zeros(BIAS_DIM))
        assert abs(r0[0]) > 0.5 or abs(r0[1]) > 1e-3


@pytest.mark.slow
def test_persistent_line_offset_no_longer_drags_the_batch():
    """The polar models' lines, each moved off its true limb the same way in every
    frame (limb 0 by 2.3 px inwards, limb 1 by 1.7 px, both turned by 2 px per
    100 px: w = 2, l = 0.3, w_s = 2, like RANSAC lines pulled in at the shaft's end),
    plus 0.5 px / 1 mrad noise: with the bias state the batch's translation error is
    well below the error without it (the markers then carry what the lines no
    longer say for sure; 18.8 -> 6.7 mm when written)."""
    robot, cam, E0, frames = sequence(120, seed=2, scene=SCENE, walk_sigma=(2.5e-5, 1e-4), marker_noise=1.0)
    rng = np.random.default_rng(5)
    moved = []
    for f in frames:
        F = base_features(robot, f.q)
        axis = ShaftAxis.make(F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0])
        L = limb_line_coefficients(f.E_true, axis, line_matrix(cam.K), False)[0]
        direction = reference_direction(E0, axis.p0, axis.d, cam.K)
        lines = [_moved_line(L[i], o, s, direction, cam.K[:2, 2]) for i, o, s in ((0, 2.3, 2.0), (1, 1.7, 2.0))]
        moved.append(np.array([l + rng.normal(0, [0.5, 1e-3]) for l in lines]))
    obs = [Observation("line-intensities-polar", lines=ln, markers=f.markers) for f, ln in zip(frames, moved)]
    errs = _batch_errors_with_and_without_bias(robot, cam, E0, frames, obs)
    assert errs[True] < 0.6 * errs[False], errs
