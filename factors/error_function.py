"""The gtsam.CustomFactor callback shared by graphtrack's single-Pose3 factors."""
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
