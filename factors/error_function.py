"""The gtsam.CustomFactor callbacks shared by graphtrack's factors: on one Pose3, or on a Pose3 and the edge-bias vector.

Another camera. ``extrinsic`` C (4x4, metres; None: the left camera itself) makes a
factor observe its image through the camera C . E (stereo: C = right_T_left, the
right camera from the left). The error function is evaluated at E' = C . E, and its
Jacobian for gtsam's right perturbation carries over unchanged:

    C . (E . Exp(xi)) = (C . E) . Exp(xi)   =>   de/dxi at E = de/dxi' at E' = C . E

(tests/test_factors_stereo.py checks it against numerical derivatives).
"""
from __future__ import annotations

import numpy as np


class PoseErrorFunction:
    """A CustomFactor error function on one Pose3 key (the frame's lumped error E).

    Subclasses implement ``evaluate(E, jacobian) -> (error, J)``: E is the 4x4
    camera-from-base matrix, J the d error / d xi for gtsam's right
    perturbation E Exp(xi), xi = (omega, v) (None when not asked for).
    ``extrinsic``: the observing camera from the left one (module doc), None: left.
    """

    extrinsic: np.ndarray | None = None

    def pose(self, values, key) -> np.ndarray:
        """The observing camera's camera-from-base pose C . E of the Pose3 at ``key``."""
        E = values.atPose3(key).matrix()
        return E if self.extrinsic is None else self.extrinsic @ E

    def evaluate(self, E, jacobian: bool):  # pragma: no cover - interface
        raise NotImplementedError

    def __call__(self, this, values, H):
        E = self.pose(values, this.keys()[0])
        e, J = self.evaluate(E, H is not None)
        if H is not None:
            H[0] = J
        return e


class PoseBiasErrorFunction(PoseErrorFunction):
    """A CustomFactor error function on the Pose3 key and, when ``on_bias``, also the
    frame's edge-bias vector (:mod:`factors.edge_bias`, a gtsam Vector key):
    ``evaluate(E, jacobian, b)`` then returns the error and [de/dxi, de/db]."""

    on_bias: bool = False

    def __call__(self, this, values, H):
        if not self.on_bias:
            return super().__call__(this, values, H)
        keys = this.keys()
        e, J = self.evaluate(self.pose(values, keys[0]), H is not None, values.atVector(keys[1]))
        if H is not None:
            H[0] = J[:, :6]
            H[1] = J[:, 6:]
        return e
