"""The no-correction baseline: E_t = E_0 (handeye.yaml) for every frame."""
from __future__ import annotations

from graphtrack.estimate.base import Estimate
from graphtrack.io.context import TrackingContext
from graphtrack.io.frame import Frame


class KinematicsEstimator:
    """Trusts the nominal hand-eye calibration and the joint readings as they are."""

    name = "kinematics"
    uses_observations = False
    offline = False
    stochastic = False
    supported_observations = ()
    extra_columns = ()

    def __init__(self, ctx: TrackingContext):
        self.E0 = ctx.handeye.copy()

    def step(self, frame: Frame, observation=None, right=None) -> Estimate:
        return Estimate(self.E0.copy())

    def finish(self):
        return None

    def report(self) -> dict:
        return {}
