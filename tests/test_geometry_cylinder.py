"""The shaft's limb lines and residuals (graphtrack.geometry.cylinder).

The reference against independent oracles: cv2.projectPoints of points found on
the contour generators by bisection (where the viewing ray is tangent) and of
points sampled over the whole surface (all on one side of each limb). The
batched and single-pose forms against the reference over many random poses,
near end-on and degenerate ones included; the Jacobians against central
differences (E . expm(xi^) by scipy)."""
import cv2
import numpy as np
import pytest
from scipy.linalg import expm

from graphtrack.geometry.cylinder import (COS_END_ON, END_ON_DEG, ShaftAxis, limb_line_coefficients,
                                          line_angles, line_matrix, line_polar, line_polar_jacobian,
                                          pixel_residual_jacobian, pixel_residuals, project_cylinder,
                                          project_cylinder_batch)
from graphtrack.geometry.lines import canonical, line_difference, pixel_residual
from graphtrack.geometry.se3 import skew, so3_exp


def tangent_points(p0, d, r, rng, n=8):
    """Points on the cylinder whose viewing ray is tangent, found WITHOUT the
    closed form: on the circle around the axis through the point of closest
    approach, the surface normal must be perpendicular to the viewing ray;
    solve cos/sin by bisection-free root finding of f(phi) = (X(phi)) . nrm(phi)."""
    d = d / np.linalg.norm(d)
    a = np.cross(d, [1.0, 0, 0])
    if np.linalg.norm(a) < 1e-3:
        a = np.cross(d, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    out = []
    for t in rng.uniform(-0.03, 0.03, n):
        c = p0 + t * d
        phis = np.linspace(0, 2 * np.pi, 3601)
        nrm = np.cos(phis)[:, None] * a + np.sin(phis)[:, None] * b
        f = np.sum((c + r * nrm) * nrm, axis=1)  # ray . normal
        for i in np.where(np.sign(f[:-1]) != np.sign(f[1:]))[0]:
            lo, hi = phis[i], phis[i + 1]
            for _ in range(60):  # bisection to machine precision
                mid = (lo + hi) / 2
                nm = np.cos(mid) * a + np.sin(mid) * b
                fm = np.dot(c + r * nm, nm)
                nl = np.cos(lo) * a + np.sin(lo) * b
                if np.sign(fm) == np.sign(np.dot(c + r * nl, nl)):
                    lo = mid
                else:
                    hi = mid
            nm = np.cos(lo) * a + np.sin(lo) * b
            out.append(c + r * nm)
    return np.array(out)


def random_cylinder(rng, f=(400, 1500), xy=0.05, z=(0.05, 0.3), r=(0.002, 0.01)):
    """Intrinsics K (focal lengths in f px) and a camera-frame cylinder: p0 (m), unit d, r (m)."""
    K = np.array([[rng.uniform(*f), 0, rng.uniform(300, 700)],
                  [0, rng.uniform(*f), rng.uniform(200, 400)], [0, 0, 1]])
    p0 = np.array([rng.uniform(-xy, xy), rng.uniform(-xy, xy), rng.uniform(*z)])
    d = rng.normal(size=3)
    return K, p0, d / np.linalg.norm(d), rng.uniform(*r)


def test_limb_lines_against_projectPoints_1000_random_cylinders():
    rng = np.random.default_rng(42)
    checked = 0
    worst = 0.0
    while checked < 1000:
        K, p0, d, r = random_cylinder(rng)
        rho, theta, valid = project_cylinder(p0, d, r, K)
        if not valid:
            continue
        X = tangent_points(p0, d, r, rng, n=3)
        X = X[X[:, 2] > 0.01]
        if len(X) == 0:
            continue
        uv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, None)
        uv = uv.reshape(-1, 2)
        res = np.abs(np.stack([pixel_residual(uv, rho[j], theta[j]) for j in range(2)], 1))  # (P, 2)
        dist = res.min(axis=1)  # each tangent point lies on one of the two limb lines
        worst = max(worst, dist.max())
        # both lines are hit
        assert len(set(np.argmin(res, axis=1))) == 2 or len(X) < 2
        checked += 1
    assert worst < 1e-6, worst


def test_vectorised_matches_single_and_flags_degenerate():
    rng = np.random.default_rng(0)
    K = np.array([[800.0, 0, 480], [0, 800, 270], [0, 0, 1]])
    p0 = rng.normal(size=(50, 3)) * 0.03 + [0, 0, 0.15]
    d = rng.normal(size=(50, 3))
    rho, theta, valid = project_cylinder(p0, d, 0.004, K)
    for i in range(50):
        r1, t1, v1 = project_cylinder(p0[i], d[i], 0.004, K)
        np.testing.assert_allclose(r1, rho[i])
        np.testing.assert_allclose(t1, theta[i])
        assert v1 == valid[i]
    # camera inside the cylinder
    _, _, v = project_cylinder(np.array([0.001, 0, 0.002]), np.array([0, 1.0, 0]), 0.004, K)
    assert not v
    # shaft behind the camera
    rho, theta, v = project_cylinder(np.array([0.0, 0.02, -0.1]), np.array([1.0, 0, 0]), 0.004, K)
    assert not v and np.all(np.isfinite(rho)) and np.all(np.isfinite(theta))
    # seen end-on (axis along the viewing ray)
    rho, theta, v = project_cylinder(np.array([0.0, 0.0, 0.1]), np.array([0, 0, 1.0]), 0.004, K)
    assert not v and np.all(np.isfinite(rho))
    assert np.all(theta >= 0) and np.all(theta < np.pi)


def test_surface_lies_on_one_side_of_each_limb_and_touches_it():
    """Points sampled over the visible cylinder's surface (not only the contour),
    projected by OpenCV: each limb line has them all on one side, the side its
    normal (A, B) points to, and the nearest is on the line (to the sampling's
    resolution)."""
    rng = np.random.default_rng(7)
    checked = 0
    while checked < 200:
        K, p0, d, r = random_cylinder(rng, f=(500, 1200), xy=0.04, z=(0.08, 0.25), r=(0.002, 0.008))
        E = np.eye(4)
        L, _, valid = limb_line_coefficients(E, ShaftAxis.make(p0, d, r), line_matrix(K), False)
        if not valid:
            continue
        a = np.cross(d, [1.0, 0, 0]) if abs(d[0]) < 0.9 else np.cross(d, [0, 1.0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(d, a)
        phi = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
        t = np.linspace(-0.03, 0.03, 7)
        ring = np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b          # (2000, 3)
        X = (p0 + t[:, None, None] * d + r * ring[None]).reshape(-1, 3)
        if X[:, 2].min() < 0.02:
            continue
        uv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, None)
        h = np.hstack([uv.reshape(-1, 2), np.ones((len(X), 1))])
        res = pixel_residuals(h, L)                                  # (P, 2)
        # the sampling's resolution: neighbours 2 pi r / 2000 apart, seen at depth z
        step = np.max(K[:2, :2]) * 2 * np.pi * r / 2000 / X[:, 2].min()
        assert res.min() > -1e-6, res.min()
        assert np.all(res.min(axis=0) < 0.5 * step ** 2 + 1e-6)    # a chord's sag ~ step^2
        # the reference's canonical lines are the same two lines
        rho, theta, v = project_cylinder(p0, d, r, K)
        assert v
        drho, dth = line_difference(*line_polar(L), rho, theta)
        assert np.abs(drho).max() < 1e-9 and np.abs(dth).max() < 1e-12
        checked += 1


def camera_poses(rng, n):
    """Camera-frame shafts (p (n, 3), unit c (n, 3)): generic, near end-on (1.8-2.2 deg
    off the viewing ray), end-on, camera inside, p behind, a limb at infinity."""
    p = rng.normal(size=(n, 3)) * [0.05, 0.05, 0.08] + [0, 0, 0.12]
    c = rng.normal(size=(n, 3))
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    k = n // 6
    # near end-on: c at an angle around END_ON_DEG from p / |p|
    pu = p[:k] / np.linalg.norm(p[:k], axis=1, keepdims=True)
    w = np.cross(pu, rng.normal(size=(k, 3)))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    ang = np.radians(rng.uniform(END_ON_DEG - 0.2, END_ON_DEG + 0.2, k))
    c[:k] = np.cos(ang)[:, None] * pu + np.sin(ang)[:, None] * w
    c[k:k + 5] = p[k:k + 5] / np.linalg.norm(p[k:k + 5], axis=1, keepdims=True)  # exactly end-on
    p[k + 5:k + 10] = rng.normal(size=(5, 3)) * 0.001                             # inside
    p[k + 10:k + 15, 2] = -np.abs(p[k + 10:k + 15, 2])                              # behind
    p[k + 15] = [0.0, 0.05, 0.004]                                                  # limb in z = 0
    c[k + 15] = [1.0, 0.0, 0.0]
    return p, c


def test_batch_matches_reference_many_poses():
    rng = np.random.default_rng(0)
    p, c = camera_poses(rng, 30000)
    K = np.array([[1000.0, 0, 640], [0, 990, 512], [0, 0, 1]])
    rho, theta, valid = project_cylinder(p, c, 0.004, K)
    rb, cos, sin, vb = project_cylinder_batch(p.T, c.T, 0.004, K)
    np.testing.assert_array_equal(valid, vb)
    assert 0.5 < valid.mean() < 0.95 and not valid[5000 + 15]
    np.testing.assert_allclose(np.hypot(cos, sin)[:, valid], 1.0, atol=1e-14)
    assert np.all(sin >= 0)
    tb = line_angles(cos, sin)
    np.testing.assert_allclose(rb.T[valid], rho[valid], rtol=1e-12, atol=1e-7)
    np.testing.assert_allclose(tb.T[valid], theta[valid], atol=1e-12)
    assert np.all(np.isfinite(rb)) and np.all(np.isfinite(tb))


def test_single_pose_matches_reference_and_flags_the_same():
    """limb_line_coefficients of E and a base-frame axis against project_cylinder of
    the same shaft in the camera frame; both normals point into the shaft's image."""
    rng = np.random.default_rng(1)
    p, c = camera_poses(rng, 1200)
    K = np.array([[900.0, 0, 500], [0, 910, 380], [0, 0, 1]])
    M = line_matrix(K)
    rho, theta, valid = project_cylinder(p, c, 0.004, K)
    for i in range(len(p)):
        R = so3_exp(rng.normal(size=3))
        t = rng.normal(size=3) * 0.1
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = R, t
        axis = ShaftAxis.make(R.T @ (p[i] - t), R.T @ c[i], 0.004)
        L, dL, ok = limb_line_coefficients(E, axis, M)
        assert ok == valid[i], i
        if not ok:
            assert dL is None
            continue
        drho, dth = line_difference(*line_polar(L), rho[i], theta[i])
        assert np.abs(drho).max() < 1e-7 and np.abs(dth).max() < 1e-10
        axis_px = np.append((K @ p[i])[:2] / p[i, 2], 1.0)
        assert np.all(pixel_residuals(axis_px[None], L) > 0)


def perturbed(E, xi):
    """E . Exp(xi), xi = (omega, v), by the matrix exponential of the twist."""
    T = np.zeros((4, 4))
    T[:3, :3], T[:3, 3] = skew(xi[:3]), xi[3:]
    return E @ expm(T)


def perturbations(E, h=1e-5):
    """E . Exp(+-k e_j) for the steps k = h, h/2 of :func:`central` (k, sign, j) -> 4x4."""
    return {(k, sg, j): perturbed(E, sg * k * e) for k in (h, h / 2) for sg in (1, -1)
            for j, e in enumerate(np.eye(6))}


def central(f, Es, h=1e-5):
    """df/dxi by central differences with one Richardson step (error O(h^4)) on the
    poses of :func:`perturbations`."""
    def diff(k):
        return np.stack([(f(Es[k, 1, j]) - f(Es[k, -1, j])) / (2 * k) for j in range(6)], -1)
    return (4.0 * diff(h / 2) - diff(h)) / 3.0


@pytest.mark.parametrize("end_on_margin_deg", [None, 1.0, 0.05])
def test_jacobians_against_central_differences(end_on_margin_deg):
    """dL/dxi, the pixel residuals' and the line parameters' Jacobians at random
    poses, generic and within a degree / 0.05 deg of the end-on threshold."""
    rng = np.random.default_rng(2)
    K = np.array([[800.0, 0, 480], [0, 820, 270], [0, 0, 1]])
    M = line_matrix(K)
    done = 0
    while done < 15:
        p = rng.normal(size=3) * [0.03, 0.03, 0.02] + [0, 0, 0.12]
        c = rng.normal(size=3)
        if end_on_margin_deg is not None:
            pu = p / np.linalg.norm(p)
            w = np.cross(pu, c)
            w /= np.linalg.norm(w)
            ang = np.radians(END_ON_DEG + end_on_margin_deg)
            c = np.cos(ang) * pu + np.sin(ang) * w
        R = expm(skew(rng.normal(size=3)))
        t = rng.normal(size=3) * 0.05
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = R, t
        # the camera at least 2 radii off the cylinder's axis (nearer, G nears singular)
        r = min(0.006, rng.uniform(0.1, 0.5) * np.linalg.norm(p - (p @ c) * c / (c @ c)))
        axis = ShaftAxis.make(R.T @ (p - t), R.T @ c, r)
        L, dL, ok = limb_line_coefficients(E, axis, M)
        if not ok:
            continue
        Es = perturbations(E)
        Ln = central(lambda F: limb_line_coefficients(F, axis, M, False)[0], Es)
        scale = np.abs(Ln).max()
        assert np.abs(dL - Ln).max() <= 1e-6 * scale
        h = np.hstack([rng.uniform(0, 960, (30, 2)), np.ones((30, 1))])
        for i in range(2):
            res = pixel_residuals(h, L)[:, i]
            J = pixel_residual_jacobian(h, L[i], dL[i], res)
            Jn = central(lambda F: pixel_residuals(h, limb_line_coefficients(F, axis, M, False)[0])[:, i], Es)
            assert np.abs(J - Jn).max() <= 1e-6 * np.abs(Jn).max()
            Jp = line_polar_jacobian(L[i]) @ dL[i]
            Jpn = central(lambda F: np.stack(line_polar(limb_line_coefficients(F, axis, M, False)[0][i])), Es)
            assert np.abs(Jp - Jpn).max() <= 1e-6 * np.abs(Jpn).max()
        done += 1


def test_residual_forms_against_the_polar_reference():
    """pixel_residuals of (A, B, C) = any multiple of (cos, sin, -rho) is
    lines.pixel_residual; line_polar gives back (rho, theta) up to representation."""
    rng = np.random.default_rng(3)
    rho = rng.uniform(-500, 500, 50)
    theta = rng.uniform(0, np.pi, 50)
    pts = rng.uniform(-100, 1000, (40, 2))
    h = np.hstack([pts, np.ones((40, 1))])
    scale = rng.uniform(-3, 3, 50)
    L = scale[:, None] * np.stack([np.cos(theta), np.sin(theta), -rho], 1)
    ref = pixel_residual(np.broadcast_to(pts, (50, 40, 2)), rho, theta).T  # (40, 50)
    np.testing.assert_allclose(pixel_residuals(h, L), np.sign(scale) * ref, atol=1e-9)
    r2, t2 = canonical(*line_polar(L))
    np.testing.assert_allclose(r2, rho, atol=1e-9)
    np.testing.assert_allclose(t2, theta, atol=1e-12)
    # d(rho, theta)/dL by central differences in L
    for Li in L[:10]:
        Jn = np.stack([(np.stack(line_polar(Li + 1e-7 * e)) - np.stack(line_polar(Li - 1e-7 * e))) / 2e-7
                       for e in np.eye(3)], 1)
        np.testing.assert_allclose(line_polar_jacobian(Li), Jn, rtol=1e-6, atol=1e-6 * np.abs(Jn).max())


def test_end_on_threshold_is_the_constant():
    """The three forms switch off at END_ON_DEG from the viewing ray, not elsewhere."""
    K = np.array([[800.0, 0, 480], [0, 800, 270], [0, 0, 1]])
    p = np.array([0.01, -0.02, 0.15])
    pu = p / np.linalg.norm(p)
    w = np.cross(pu, [1.0, 0, 0])
    w /= np.linalg.norm(w)
    for deg, expect in [(END_ON_DEG - 1e-6, False), (END_ON_DEG + 1e-6, True)]:
        c = np.cos(np.radians(deg)) * pu + np.sin(np.radians(deg)) * w
        assert bool(project_cylinder(p, c, 0.004, K)[2]) is expect
        assert bool(project_cylinder_batch(p[:, None], c[:, None], 0.004, K)[3][0]) is expect
        assert limb_line_coefficients(np.eye(4), ShaftAxis.make(p, c, 0.004), line_matrix(K))[2] is expect
    assert COS_END_ON == pytest.approx(np.cos(np.radians(END_ON_DEG)))


def test_inward_sides_point_into_the_shaft_image_foreshortened_views_included():
    """``sides``: the sign of each limb line's residual at the projected axis point (the
    pinhole projection of p0, an oracle apart from the limb planes), on every valid pose in
    front of the camera, among them shafts pointing nearly at it, where the limbs converge
    steeply (a side taken from either line's foot point, exact for parallel limbs, fails
    there)."""
    rng = np.random.default_rng(1)
    p, c = camera_poses(rng, 20000)
    K = np.array([[1000.0, 0, 640], [0, 990, 512], [0, 0, 1]])
    rho, cos, sin, valid, inward = project_cylinder_batch(p.T, c.T, 0.004, K, sides=True)
    tilt = np.degrees(np.arccos(np.clip(np.abs(np.sum(c * p, axis=1)) / np.linalg.norm(p, axis=1), 0, 1)))
    ok = valid & (p[:, 2] > 0.01)
    assert np.sum(ok & (tilt < 20)) > 100                        # steep views are among them
    uv = (p @ K.T)[:, :2] / p[:, 2:3]                            # the axis point's pixel
    res = cos * uv[:, 0] + sin * uv[:, 1] - rho                  # (2, N)
    np.testing.assert_array_equal(np.sign(res)[:, ok], inward[:, ok])
    # a line moved w along inward is w nearer the axis point's pixel
    moved = (rho + 0.5 * inward) - rho
    np.testing.assert_allclose(np.abs(res - moved)[:, ok], np.abs(res)[:, ok] - 0.5, atol=1e-9)
