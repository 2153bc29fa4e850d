"""SE(3) and the lumped-error parameterisation (b, w), vectorised over leading axes.

The lumped error is written as a translation b (metres) and an axis-angle
rotation w (radians, |w| = angle):

    E(b, w) = [ R(w)  b ]        R(w) = exp([w]x)  (Rodrigues)
              [ 0     1 ]

Every function accepts arrays with any number of leading axes ("...") so that
thousands of particle hypotheses are handled without a Python loop.
Quaternions are (x, y, z, w) as in the TUM format.
"""
from __future__ import annotations

import numpy as np

_SMALL = 1e-8


def skew(w: np.ndarray) -> np.ndarray:
    """[w]x for w of shape (..., 3) -> (..., 3, 3): [w]x a = w x a, and the rows of
    P @ [w]x are the rows of P crossed with w."""
    w = np.asarray(w, dtype=float)
    if w.shape == (3,):  # one vector (the factors' callbacks): without the stacking
        return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    z = np.zeros(w.shape[:-1])
    return np.stack([
        np.stack([z, -w[..., 2], w[..., 1]], -1),
        np.stack([w[..., 2], z, -w[..., 0]], -1),
        np.stack([-w[..., 1], w[..., 0], z], -1),
    ], -2)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: R = I + sin(t)/t [w]x + (1 - cos t)/t^2 [w]x^2, t = |w|.

    Uses the Taylor series below t = 1e-4 (exact to double precision), so
    w = 0 gives I with no NaN.
    """
    w = np.asarray(w, dtype=float)
    t2 = np.sum(w * w, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - np.cos(ts)) / (ts * ts))
    K = skew(w)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def so3_exp_batch(w: np.ndarray) -> np.ndarray:
    """:func:`so3_exp` of axis-angle rows w (N, 3) (rad), components first: (3, 3, N).

    R[i, j] is an (N,) array, the layout of vectorised per-hypothesis arithmetic
    (the particle filter's projections). Written out entry by entry,
    [w]x^2 = w w^T - t^2 I, so R = I + A [w]x + B (w w^T - t^2 I) with
    A = sin t / t, B = (1 - cos t) / t^2, t = |w|; below t^2 = 1e-8 the
    series A = 1 - t^2/6, B = 1/2 - t^2/24 (the next terms are below double
    precision there), so w = 0 gives I with no NaN.
    """
    wx, wy, wz = np.ascontiguousarray(np.asarray(w, float).reshape(-1, 3).T)
    t2 = wx * wx + wy * wy + wz * wz
    small = t2 < 1e-8
    t = np.sqrt(np.where(small, 1.0, t2))
    A = np.where(small, 1.0 - t2 / 6.0, np.sin(t) / t)
    B = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    bxy, bxz, byz = B * wx * wy, B * wx * wz, B * wy * wz
    ax, ay, az = A * wx, A * wy, A * wz
    R = np.empty((3, 3, len(wx)))
    R[0, 0] = 1.0 + B * (wx * wx - t2)
    R[1, 1] = 1.0 + B * (wy * wy - t2)
    R[2, 2] = 1.0 + B * (wz * wz - t2)
    R[0, 1], R[1, 0] = bxy - az, bxy + az
    R[0, 2], R[2, 0] = bxz + ay, bxz - ay
    R[1, 2], R[2, 1] = byz - ax, byz + ax
    return R


def so3_log(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`so3_exp`, returning w with |w| in [0, pi].

    Near 0 uses the first-order series; near pi extracts the axis from the
    symmetric part R + R^T = 2 cos(t) I + 2 (1 - cos t) a a^T, taking the
    sign from the antisymmetric part where it is still informative.
    """
    R = np.asarray(R, dtype=float)
    tr = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    t = np.arccos(tr)
    vee = np.stack([R[..., 2, 1] - R[..., 1, 2],
                    R[..., 0, 2] - R[..., 2, 0],
                    R[..., 1, 0] - R[..., 0, 1]], -1)
    st = np.sin(t)
    small = t < 1e-4
    near_pi = t > np.pi - 1e-3
    generic = ~(small | near_pi)
    scale = np.where(generic, t / (2.0 * np.where(generic, st, 1.0)), 0.5 + t * t / 12.0)
    w = scale[..., None] * vee
    if np.any(near_pi):
        # (R + R^T)/2 - cos(t) I = (1 - cos t) a a^T: its largest column is +-a
        B = (R + np.swapaxes(R, -1, -2)) / 2.0 - np.cos(t)[..., None, None] * np.eye(3)
        k = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        col = np.take_along_axis(B, k[..., None, None].repeat(3, -1), -1)[..., 0]
        axis = col / np.maximum(np.linalg.norm(col, axis=-1, keepdims=True), 1e-300)
        sign = np.sign(np.sum(axis * vee, axis=-1))  # vee = 2 sin(t) a
        sign = np.where(sign == 0, 1.0, sign)
        w = np.where(near_pi[..., None], (sign * t)[..., None] * axis, w)
    return w


def bw_to_matrix(bw: np.ndarray) -> np.ndarray:
    """(..., 6) [b (m), w (rad)] -> (..., 4, 4) homogeneous transform E(b, w)."""
    bw = np.asarray(bw, dtype=float)
    T = np.zeros(bw.shape[:-1] + (4, 4))
    T[..., :3, :3] = so3_exp(bw[..., 3:6])
    T[..., :3, 3] = bw[..., :3]
    T[..., 3, 3] = 1.0
    return T


def matrix_to_bw(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) -> (..., 6) [b, w]; inverse of :func:`bw_to_matrix`."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[..., :3, 3], so3_log(T[..., :3, :3])], -1)


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4) without a general matrix inverse."""
    T = np.asarray(T, dtype=float)
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    Ti[..., 3, 3] = 1.0
    return Ti


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply (..., 4, 4) to points (..., 3) (broadcasting leading axes)."""
    T = np.asarray(T, dtype=float)
    p = np.asarray(p, dtype=float)
    return (T[..., :3, :3] @ p[..., None])[..., 0] + T[..., :3, 3]


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Rotation (..., 3, 3) -> unit quaternion (..., 4) as (x, y, z, w), w >= 0."""
    R = np.asarray(R, dtype=float)[..., :3, :3]
    w = so3_log(R)
    t = np.linalg.norm(w, axis=-1)
    half = t / 2.0
    s = np.where(t < 1e-8, 0.5 - t * t / 48.0, np.sin(half) / np.where(t < 1e-8, 1.0, t))
    q = np.concatenate([s[..., None] * w, np.cos(half)[..., None]], -1)
    q = np.where(q[..., 3:4] < 0, -q, q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Quaternion (..., 4) as (x, y, z, w) -> rotation (..., 3, 3); normalises q."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack rotation (..., 3, 3) and translation (..., 3) into (..., 4, 4)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def average_rotations(R: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted chordal L2 mean of rotations (N, 3, 3) -> (3, 3).

    argmin_R sum_i w_i ||R - R_i||_F^2 = the projection of sum_i w_i R_i onto
    SO(3) by SVD (with the determinant fixed to +1).
    """
    R = np.asarray(R, dtype=float)
    w = np.ones(len(R)) if weights is None else np.asarray(weights, dtype=float)
    return project_to_so3(np.einsum("n,nij->ij", w, R))


def is_rotation(R, atol: float = 1e-4) -> bool:
    """Whether R is a finite 3x3 rotation matrix: R R^T = I within ``atol``, det R > 0 (no
    reflection)."""
    R = np.asarray(R, dtype=float)
    return (R.shape == (3, 3) and bool(np.all(np.isfinite(R))) and np.allclose(R @ R.T, np.eye(3), atol=atol)
            and np.linalg.det(R) > 0)


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (deg) of Ra Rb^T, the rotation between them, for (..., 3, 3) stacks."""
    D = np.einsum("...ij,...kj->...ik", np.asarray(Ra, float), np.asarray(Rb, float))
    c = np.clip((np.trace(D, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(c))


def is_rigid(T, atol: float = 1e-4) -> bool:
    """Whether T is a finite 4x4 rigid transform: a rotation (:func:`is_rotation`), a finite
    translation and the last row 0 0 0 1."""
    T = np.asarray(T, dtype=float)
    return (T.shape == (4, 4) and bool(np.all(np.isfinite(T))) and np.allclose(T[3], [0, 0, 0, 1])
            and is_rotation(T[:3, :3], atol))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """The rotation nearest a 3x3 matrix M in Frobenius norm: U diag(1, 1, det(U V^T)) V^T."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def to_pose3(T: np.ndarray):
    """4x4 numpy -> gtsam.Pose3."""
    import gtsam  # lazy: geometry is below every layer; only the factor graphs may load gtsam

    return gtsam.Pose3(np.asarray(T, dtype=float))


def from_pose3(pose) -> np.ndarray:
    """gtsam.Pose3 -> 4x4 numpy."""
    return np.asarray(pose.matrix(), dtype=float)


def rot_x(a: np.ndarray | float) -> np.ndarray:
    """Homogeneous rotation about x by a (rad), vectorised over a's shape."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    T = np.zeros(a.shape + (4, 4))
    T[..., 0, 0] = 1
    T[..., 1, 1], T[..., 1, 2], T[..., 2, 1], T[..., 2, 2] = c, -s, s, c
    T[..., 3, 3] = 1
    return T


def rot_z(a: np.ndarray | float) -> np.ndarray:
    """Homogeneous rotation about z by a (rad), vectorised over a's shape."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    T = np.zeros(a.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1] = c, -s, s, c
    T[..., 2, 2] = 1
    T[..., 3, 3] = 1
    return T


def trans(x: np.ndarray | float = 0.0, y: np.ndarray | float = 0.0,
          z: np.ndarray | float = 0.0) -> np.ndarray:
    """Homogeneous translation, vectorised over the broadcast shape of x, y, z."""
    x, y, z = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(z, float))
    T = np.zeros(x.shape + (4, 4))
    T[..., 0, 0] = T[..., 1, 1] = T[..., 2, 2] = T[..., 3, 3] = 1
    T[..., 0, 3], T[..., 1, 3], T[..., 2, 3] = x, y, z
    return T
