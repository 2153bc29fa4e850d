"""Painted-disc marker centroids against an independent ray caster.

The oracle casts a ray through every point of a fine pixel grid around the
marker, intersects it with the cylinder (nearest root of the quadratic),
converts the hit to surface coordinates (arc length, axial offset) and keeps
the rays landing inside the disc: their mean pixel is the blob's centroid.
"""
import numpy as np
import pytest

from graphtrack.geometry.painted_marker import disc_centroid, disc_pattern, on_surface, painted_disc

K = np.array([[1000.0, 0, 480.0], [0, 1000.0, 270.0], [0, 0, 1]])
R_SHAFT, R_DISC = 0.004, 0.0011
P0 = np.array([0.004, -0.002, 0.09])
D = np.array([1.0, 0.35, 0.25]) / np.linalg.norm([1.0, 0.35, 0.25])


def marker_at(angle):
    """Surface point at ``angle`` rad around the axis from the meridian facing the camera."""
    toward = -(P0 - (P0 @ D) * D)                 # from the axis towards the camera centre
    n0 = toward / np.linalg.norm(toward)
    t0 = np.cross(D, n0)
    return P0 + 0.003 * D + R_SHAFT * (np.cos(angle) * n0 + np.sin(angle) * t0)


def ray_cast_centroid(P, step=0.04, half=25.0):
    uv0 = (K @ P)[:2] / P[2]
    g = np.arange(-half, half, step)
    u, v = np.meshgrid(uv0[0] + g, uv0[1] + g)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    # |(t ray - P0) x D|^2 = r^2
    a = np.cross(rays, D)
    b = np.cross(-P0, D)
    A, B, C = (a * a).sum(1), 2 * (a @ b), b @ b - R_SHAFT ** 2
    disc = B ** 2 - 4 * A * C
    hit = disc >= 0
    t = (-B[hit] - np.sqrt(disc[hit])) / (2 * A[hit])
    H = t[:, None] * rays[hit]
    n_k = (P - P0) - ((P - P0) @ D) * D
    n_k /= np.linalg.norm(n_k)
    t_k = np.cross(D, n_k)
    w = H - P0
    h = w @ D - (P - P0) @ D
    s = R_SHAFT * np.arctan2(w @ t_k, w @ n_k)
    inside = s ** 2 + h ** 2 <= R_DISC ** 2
    uv = np.stack([u.reshape(-1)[hit], v.reshape(-1)[hit]], 1)[inside]
    return uv.mean(0), len(uv)


def model_centroid(P, n=9):
    X, N = painted_disc(P[None], P0, D, R_SHAFT, R_DISC, n)
    return disc_centroid(X, N, K)[0]


@pytest.mark.parametrize("angle", [0.0, 0.6, 1.1, 1.45])
def test_centroid_matches_ray_casting(angle):
    P = marker_at(angle)
    oracle, count = ray_cast_centroid(P)
    assert count > 500
    assert np.linalg.norm(model_centroid(P, 41) - oracle) < 0.02
    assert np.linalg.norm(model_centroid(P, 9) - oracle) < 0.1      # the factors' default
    centre = (K @ P)[:2] / P[2]
    if angle >= 1.1:              # seen obliquely the centre's projection is off by > 0.5 px
        assert np.linalg.norm(centre - oracle) > 0.5


def test_hidden_disc_is_nan_and_surface_test():
    P = marker_at(np.pi)                          # on the far side
    assert np.all(np.isnan(model_centroid(P)))
    assert on_surface(np.stack([marker_at(0.3), P0 + 0.001 * D]), P0, D, R_SHAFT).tolist() == [True, False]


def test_pattern_is_equal_area_inside_the_disc():
    s, h = disc_pattern(R_DISC, 9)
    assert np.all(s ** 2 + h ** 2 <= R_DISC ** 2) and len(s) == 69
    # the samples' second moment matches the disc's, R^2 / 4, to within the grid
    assert np.mean(s ** 2) == pytest.approx(R_DISC ** 2 / 4, rel=0.1)
