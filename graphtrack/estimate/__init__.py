"""Estimators of the lumped error E_t, all behind one streaming interface
(:class:`graphtrack.estimate.base.Estimator`): ``step(frame, observation) -> Estimate``.

``make_estimator(name, ctx, **options)`` builds one by name:
kinematics (baseline), pf (the method's particle filter), smoother (fixed-lag
factor graph), batch (offline Levenberg-Marquardt over the whole recording).
"""
from __future__ import annotations

import importlib

from graphtrack.errors import InputError

#: name -> (module, class)
ESTIMATORS = {
    "kinematics": ("graphtrack.estimate.kinematics", "KinematicsEstimator"),
    "pf": ("graphtrack.estimate.particle_filter", "ParticleFilter"),
    "smoother": ("graphtrack.estimate.smoother", "FixedLagSmootherEstimator"),
    "batch": ("graphtrack.estimate.batch", "BatchEstimator"),
}

#: estimators that cannot run without a shaft feature in robot.json
NEEDS_SHAFT = {"pf": "particle filter"}


def make_estimator(name: str, ctx, **options):
    """Instantiate estimator ``name`` with the tracking context and its options."""
    if name not in ESTIMATORS:
        raise InputError(f"--estimator: unknown estimator {name!r} (choose from {', '.join(ESTIMATORS)})")
    if name in NEEDS_SHAFT and not getattr(getattr(ctx, "robot", None), "shaft_features", True):
        raise InputError(f"robot.json has no shaft_features: the {NEEDS_SHAFT[name]} needs the shaft's "
                         "cylinder (its silhouette edges are what it observes)")
    module, cls = ESTIMATORS[name]
    return getattr(importlib.import_module(module), cls)(ctx, **options)
