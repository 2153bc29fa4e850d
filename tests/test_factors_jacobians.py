"""Analytic Jacobians of the factors against central differences on Pose3.retract,
the robust kernels against gtsam's mEstimators, degenerate views."""
import gtsam
import numpy as np
import pytest

from factors.limb import LimbPairing
from factors.line_parameter import LineParameterError, line_parameter_factor
from factors.marker import MarkerError, associate, marker_factor
from factors.robust import make_kernel
from factors.shaft_pixels import ShaftPixelsError, shaft_pixels_factor
from graphtrack.sim.synthetic import sequence
from graphtrack.geometry.cylinder import ShaftAxis, limb_line_coefficients
from graphtrack.robot.features import base_features

#: (sigma_rho px, sigma_theta rad) of a detected line in these tests (the estimators pass FactorOptions')
LINE_SIGMAS = (3.0, 0.01)


@pytest.fixture(scope="module")
def scene():
    robot, cam, E0, fr = sequence(2, seed=3, outliers=0.2, pixel_noise=2.0, line_noise=(2.0, 0.01),
                                  marker_noise=2.0)
    f = fr[1]
    F = base_features(robot, f.q)
    axis = ShaftAxis.make(F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0])
    return robot, cam, E0, f, F, axis


def numerical(fn, pose, h=1e-7):
    cols = []
    for k in range(6):
        x = np.zeros(6)
        x[k] = h
        a = fn.evaluate(pose.retract(x).matrix(), False)[0]
        b = fn.evaluate(pose.retract(-x).matrix(), False)[0]
        cols.append((a - b) / (2 * h))
    return np.stack(cols, 1)


def check(fn, pose, tol=1e-6):
    e, J = fn.evaluate(pose.matrix())
    Jn = numerical(fn, pose)
    assert J.shape == (len(e), 6)
    assert np.max(np.abs(J - Jn)) <= tol * np.max(np.abs(Jn))
    return e, J


@pytest.mark.parametrize("kernel", ["none", "huber", "cauchy"])
def test_shaft_pixels_jacobian(scene, kernel):
    robot, cam, E0, f, F, axis = scene
    for i in range(2):
        fn = ShaftPixelsError(f.pixels[i], axis, cam.K, 1.5, kernel)
        # also away from the truth (the hand-eye error)
        for E in (f.E_true, E0):
            e, _ = check(fn, gtsam.Pose3(E), tol=2e-6 if kernel == "huber" else 1e-6)
            assert e.shape == (len(f.pixels[i]),)
        fn.evaluate(f.E_true)
        assert fn.limb == i          # assigned to its own projected edge


@pytest.mark.parametrize("kernel", ["none", "huber"])
def test_tempered_pixel_set_scales_the_cost(scene, kernel):
    """weight w: e = sqrt(w) e_1 and J = sqrt(w) J_1, so the cost is w times the
    untempered one; the Jacobian still matches central differences."""
    robot, cam, E0, f, F, axis = scene
    full = ShaftPixelsError(f.pixels[0], axis, cam.K, 1.5, kernel)
    part = ShaftPixelsError(f.pixels[0], axis, cam.K, 1.5, kernel, weight=0.25)
    e1, J1 = full.evaluate(E0)
    e, J = check(part, gtsam.Pose3(E0), tol=2e-6)
    assert np.allclose(e, 0.5 * e1) and np.allclose(J, 0.5 * J1)
    assert np.allclose(part.costs(limb_line_coefficients(E0, axis, part.M, False)[0]),
                       0.25 * full.costs(limb_line_coefficients(E0, axis, full.M, False)[0]))


def test_pairing_gives_the_two_edges_different_limbs(scene):
    """Shift E sideways by ~0.7 shaft widths: both pixel sets (and both detected
    lines) are then nearer the same projected limb; alone each takes it, paired
    they take one limb each (the cheaper pairing), and the Jacobians still
    match central differences."""
    robot, cam, E0, f, F, axis = scene
    from graphtrack.geometry.cylinder import project_cylinder
    from graphtrack.geometry.se3 import bw_to_matrix

    Ft = F.transformed(f.E_true)
    rho, theta, _ = project_cylinder(Ft.shaft_p0[0], Ft.shaft_d[0], Ft.shaft_r[0], cam.K)
    width = abs(rho[0] - rho[1])
    n = np.array([np.cos(theta[0]), np.sin(theta[0]), 0.0])
    depth = Ft.shaft_p0[0][2]
    E = bw_to_matrix(np.r_[0.7 * width * depth / cam.K[0, 0] * n, 0, 0, 0]) @ f.E_true
    alone = [ShaftPixelsError(f.pixels[i], axis, cam.K, 1.5, "huber") for i in range(2)]
    for fn in alone:
        fn.evaluate(E, False)
    assert alone[0].limb == alone[1].limb
    pairing = LimbPairing()
    paired = [ShaftPixelsError(f.pixels[i], axis, cam.K, 1.5, "huber", pairing) for i in range(2)]
    for fn in paired:
        check(fn, gtsam.Pose3(E), tol=2e-6)
    assert {paired[0].limb, paired[1].limb} == {0, 1}
    L = limb_line_coefficients(E, axis, paired[0].M, False)[0]
    cost = [fn.costs(L) for fn in paired]
    chosen = cost[0][paired[0].limb] + cost[1][paired[1].limb]
    assert chosen <= cost[0][1 - paired[0].limb] + cost[1][1 - paired[1].limb]
    for fn in paired:                     # at the truth each set keeps its own limb
        fn.evaluate(f.E_true, False)
    assert [fn.limb for fn in paired] == [0, 1]
    # the same for the two detected lines of the polar models
    lone = [LineParameterError(f.lines[i], axis, cam.K, *LINE_SIGMAS) for i in range(2)]
    for fn in lone:
        fn.evaluate(E, False)
    assert lone[0].limb == lone[1].limb
    pairing = LimbPairing()
    lines = [LineParameterError(f.lines[i], axis, cam.K, *LINE_SIGMAS, pairing=pairing) for i in range(2)]
    for fn in lines:
        check(fn, gtsam.Pose3(E))
    assert {lines[0].limb, lines[1].limb} == {0, 1}


def test_line_parameter_jacobian_and_wrap(scene):
    robot, cam, E0, f, F, axis = scene
    for i in range(2):
        fn = LineParameterError(f.lines[i], axis, cam.K, *LINE_SIGMAS)
        check(fn, gtsam.Pose3(E0))
        r, _ = fn.evaluate(f.E_true)
        assert fn.limb == i and abs(r[1]) < 0.05
        # the same line in its other representation gives the same residual
        rho, th = f.lines[i]
        fn2 = LineParameterError([-rho, th + np.pi], axis, cam.K, *LINE_SIGMAS)
        r2, _ = fn2.evaluate(f.E_true)
        np.testing.assert_allclose(r2, r, atol=1e-9)


@pytest.mark.parametrize("kernel", ["none", "huber", "cauchy"])
def test_marker_jacobian_and_gate(scene, kernel):
    robot, cam, E0, f, F, axis = scene
    pose = gtsam.Pose3(f.E_true).retract(np.array([1e-3, -5e-4, 2e-4, 5e-4, 1e-4, -2e-4]))
    fn = MarkerError(f.markers, F.points, cam.K, 2.0, 20.0, kernel)
    e, _ = check(fn, pose)
    assert np.all(fn.assoc >= 0) and np.any(e != 0)
    # a detection far from every projected marker is gated out: zero residual
    far = np.vstack([f.markers, f.markers[:1] + 80.0])
    fn = MarkerError(far, F.points, cam.K, 2.0, 20.0, kernel)
    e, J = fn.evaluate(pose.matrix())
    assert fn.assoc[-1] == -1 and np.all(e[-2:] == 0) and np.all(J[-2:] == 0)


def test_marker_association_ignores_detections_beyond_the_gate():
    """Hand-computed: markers at x = 0 and 20 px, a detection 0.5 px from the first and
    one far off (1000 px from the first, 1020 from the second). Raw distances would pair
    the near detection with the second marker (19.5 + 1000 < 0.5 + 1020); the gate caps
    both far costs alike, so the near one keeps the first marker and the far one none."""
    predicted = np.array([[0.0, 0.0], [20.0, 0.0]])
    detected = np.array([[0.5, 0.0], [-1000.0, 0.0]])
    np.testing.assert_array_equal(associate(predicted, detected, gate=25.0), [0, -1])
    # a marker that is not usable (behind the camera) is never paired, however near
    np.testing.assert_array_equal(associate(predicted, detected, 25.0, usable=np.array([False, True])),
                                  [1, -1])
    # among detections within the gate, the assignment still minimises the summed distance
    np.testing.assert_array_equal(associate(predicted, np.array([[18.0, 0.0], [3.0, 0.0]]), 25.0),
                                  [1, 0])


@pytest.mark.parametrize("kind,k", [("huber", 1.345), ("cauchy", 2.0)])
def test_kernels_match_gtsam(kind, k):
    kern = make_kernel(kind, k)
    est = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[kind].Create(k)
    for x in (0.0, 0.5, 1.3, 3.0, 12.0):
        assert kern.loss(np.array([x]))[0] == pytest.approx(est.loss(x), rel=1e-9, abs=1e-12)
        # 0.5 |e|^2 == rho for the reweighted residual
        e, _ = kern.apply_scalar(np.array([x]), None)
        assert 0.5 * e[0] ** 2 == pytest.approx(est.loss(x), rel=1e-9, abs=1e-12)


def test_gtsam_factors_wrap_the_error_functions(scene):
    robot, cam, E0, f, F, axis = scene
    v = gtsam.Values()
    x = gtsam.symbol("x", 0)
    v.insert(x, gtsam.Pose3(E0))
    fs = [shaft_pixels_factor(x, f.pixels[0], axis, cam.K, 1.5, "cauchy"),
          line_parameter_factor(x, f.lines[0], axis, cam.K, *LINE_SIGMAS, "cauchy"),
          marker_factor(x, f.markers, F.points, cam.K, 2.0, 20.0, "cauchy")]
    for fac in fs:
        assert np.isfinite(fac.error(v))
        gf = fac.linearize(v)
        A = gf.jacobian()[0]
        assert A.shape[1] == 6 and np.all(np.isfinite(A))
    assert shaft_pixels_factor(x, np.zeros((0, 2)), axis, cam.K, 1.5, "cauchy") is None
    assert marker_factor(x, np.zeros((0, 2)), F.points, cam.K, 2.0, 20.0, "cauchy") is None


def test_degenerate_view_is_silent(scene):
    robot, cam, E0, f, F, axis = scene
    # shaft axis through the optical centre (end-on) and behind the camera
    Einv = np.linalg.inv(E0)
    on_axis = ShaftAxis.make(Einv[:3, 3] + 0.1 * Einv[:3, 2], Einv[:3, 2], 0.004)
    behind = ShaftAxis.make(Einv[:3, 3] - 0.1 * Einv[:3, 2], Einv[:3, 0], 0.004)
    for ax in (on_axis, behind):
        for fn in (ShaftPixelsError(f.pixels[0], ax, cam.K, 1.5, "cauchy"),
                   LineParameterError(f.lines[0], ax, cam.K, *LINE_SIGMAS)):
            e, J = fn.evaluate(E0)
            assert np.all(e == 0) and np.all(J == 0) and fn.limb == -1


@pytest.mark.parametrize("kernel", ["none", "cauchy"])
def test_painted_disc_marker_jacobian(scene, kernel):
    """The disc-centroid prediction's Jacobian (weights, visibility and all), also
    with a point feature off the shaft mixed in (kept a point)."""
    from graphtrack.robot.features import marker_discs

    robot, cam, E0, f, F, axis = scene
    discs = marker_discs(robot, F)
    assert discs is not None and np.all(np.linalg.norm(discs[1], axis=-1) > 0.99)
    pose = gtsam.Pose3(f.E_true).retract(np.array([1e-3, -5e-4, 2e-4, 5e-4, 1e-4, -2e-4]))
    fn = MarkerError(f.markers, F.points, cam.K, 2.0, 60.0, kernel, discs)
    e, _ = check(fn, pose)
    assert np.all(fn.assoc >= 0) and np.any(e != 0)
    # marker 0 turned into a point: the same as the point model for it
    X, N = discs[0].copy(), discs[1].copy()
    X[0], N[0] = F.points[0], 0.0
    fn = MarkerError(f.markers, F.points, cam.K, 2.0, 60.0, kernel, (X, N))
    check(fn, pose)
    c, usable, _ = fn.predict(pose.matrix())
    c_point, _, _ = MarkerError(f.markers, F.points, cam.K, 2.0, 20.0, "cauchy").predict(pose.matrix())
    np.testing.assert_allclose(c[0], c_point[0], atol=1e-9)
    # a visible disc is off its centre's projection; a hidden one is predicted at it
    from graphtrack.geometry.painted_marker import disc_centroid

    E = pose.matrix()
    hidden = np.isnan(disc_centroid(X @ E[:3, :3].T + E[:3, 3], N @ E[:3, :3].T, cam.K)[:, 0])
    hidden[0] = False
    assert hidden.any() and not hidden[1:].all()
    gap = np.linalg.norm(c - c_point, axis=1)
    assert np.all(gap[1:][~hidden[1:]] > 1e-3) and np.all(gap[hidden] < 1e-9)
