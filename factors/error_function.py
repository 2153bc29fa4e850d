"""The gtsam.CustomFactor callbacks shared by graphtrack's factors: on one Pose3, or on a Pose3 and the edge-bias vector."""
from __future__ import annotations


class PoseErrorFunction:
    """A CustomFactor error function on one Pose3 key (the frame's lumped error E).

    Subclasses implement ``evaluate(E, jacobian) -> (error, J)``: E is the 4x4
    camera-from-base matrix, J the d error / d xi for gtsam's right
    perturbation E Exp(xi), xi = (omega, v) (None when not asked for).
    """

    def evaluate(self, E, jacobian: bool):  # pragma: no cover - interface
        raise NotImplementedError

    def __call__(self, this, values, H):
        E = values.atPose3(this.keys()[0]).matrix()
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
        e, J = self.evaluate(values.atPose3(keys[0]).matrix(), H is not None, values.atVector(keys[1]))
        if H is not None:
            H[0] = J[:, :6]
            H[1] = J[:, 6:]
        return e
