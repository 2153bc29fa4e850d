"""The pinhole projection through intrinsics K, and its Jacobian: the estimators' and
factors' form (K as an array, batched, no distortion; the distorted camera model is
:class:`graphtrack.geometry.camera.Camera`).

For a camera-frame point X = (X, Y, Z) (m) and K = [[f_x, 0, c_x], [0, f_y, c_y], [0, 0, 1]]:

    pi(X)      = (f_x X / Z + c_x,  f_y Y / Z + c_y)                 undistorted px
    dpi / dX   = [[f_x / Z, 0, -f_x X / Z^2],
                  [0, f_y / Z, -f_y Y / Z^2]]                          px / m

computed with one reciprocal, iz = 1 / Z: u = f_x X iz + c_x.

A point with Z <= Z_MIN is behind the camera (or in its plane). Its inverse depth is
``behind``: NaN by default, so its pixels and derivatives are NaN; a caller that masks
such points itself and needs the arithmetic around them to stay finite (a weighted sum,
a matrix product over all points) passes a finite stand-in, e.g. 1.0.
"""
from __future__ import annotations

import numpy as np

#: depth (m) at or below which a point is behind the camera
Z_MIN = 1e-9


def inverse_depth(Z, behind: float = np.nan) -> np.ndarray:
    """1 / Z (1/m) for depths Z (any shape), ``behind`` (finite or NaN) where Z <= Z_MIN."""
    stand_in = np.inf if behind == 0 else 1.0 / behind     # the depth whose reciprocal is `behind`
    return 1.0 / np.where(np.asarray(Z) > Z_MIN, Z, stand_in)


def pixels(K: np.ndarray, X, Y, Z, behind: float = np.nan) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) px of camera-frame coordinates given apart (m, any one shape, e.g. a
    coordinate-first (3, M, N) array's rows); ``behind`` as in the module doc."""
    iz = inverse_depth(Z, behind)
    return K[0, 0] * X * iz + K[0, 2], K[1, 1] * Y * iz + K[1, 2]


def project(K: np.ndarray, points: np.ndarray, behind: float = np.nan, iz: np.ndarray | None = None) -> np.ndarray:
    """Camera-frame points (..., 3) m -> undistorted pixels (..., 2) px (module doc);
    iz: the points' :func:`inverse_depth` when the caller has it."""
    P = np.asarray(points, float)
    iz = (inverse_depth(P[..., 2], behind) if iz is None else iz)[..., None]
    return P[..., :2] * K.diagonal()[:2] * iz + K[:2, 2]


def jacobian(K: np.ndarray, points: np.ndarray, behind: float = np.nan, iz: np.ndarray | None = None) -> np.ndarray:
    """dpi / dX (..., 2, 3) px/m at camera-frame points (..., 3) m (module doc); iz as in
    :func:`project`."""
    P = np.asarray(points, float)
    iz = (inverse_depth(P[..., 2], behind) if iz is None else iz)[..., None]
    s = K.diagonal()[:2] * iz                     # (f_x / Z, f_y / Z)
    J = np.zeros(P.shape[:-1] + (2, 3))
    J[..., 0, 0], J[..., 1, 1] = s[..., 0], s[..., 1]
    J[..., 2] = -s * P[..., :2] * iz             # (-f_x X / Z^2, -f_y Y / Z^2)
    return J
