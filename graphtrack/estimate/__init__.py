"""Estimators of the lumped error E_t, all behind one streaming interface
(:class:`graphtrack.estimate.base.Estimator`): ``step(frame, observation) -> Estimate``.

``make_estimator(name, ctx, **options)`` builds one by name:
kinematics (baseline), pf (the method's particle filter), smoother (fixed-lag
factor graph), batch (offline Levenberg-Marquardt over the whole recording).
``estimator_class(name)`` gives its class (the protocol's class attributes)
without building it.
"""
from __future__ import annotations

import importlib

from graphtrack.errors import InputError

#: name -> (module, class); a module is imported only when its estimator is asked for
#: (the factor-graph estimators need gtsam)
ESTIMATORS = {
    "kinematics": ("graphtrack.estimate.kinematics", "KinematicsEstimator"),
    "pf": ("graphtrack.estimate.particle_filter", "ParticleFilter"),
    "smoother": ("graphtrack.estimate.smoother", "FixedLagSmootherEstimator"),
    "batch": ("graphtrack.estimate.batch", "BatchEstimator"),
}

#: estimators that cannot run without a shaft feature in robot.json
NEEDS_SHAFT = {"pf": "particle filter"}


def estimator_class(name: str) -> type:
    """The class of estimator ``name`` (unknown names raise InputError)."""
    if name not in ESTIMATORS:
        raise InputError(f"--estimator: unknown estimator {name!r} (choose from {', '.join(ESTIMATORS)})")
    module, cls = ESTIMATORS[name]
    return getattr(importlib.import_module(module), cls)


def require_shaft(name: str, robot, where="robot.json") -> None:
    """InputError naming ``where`` (the robot description) when estimator ``name`` needs a
    shaft feature (NEEDS_SHAFT) and ``robot`` has none."""
    if name in NEEDS_SHAFT and not robot.shaft_features:
        raise InputError(f"{where}: no shaft_features: the {NEEDS_SHAFT[name]} needs the shaft's "
                         "cylinder (its silhouette edges are what it observes)")


def make_estimator(name: str, ctx, **options):
    """Instantiate estimator ``name`` with the tracking context and its options."""
    cls = estimator_class(name)
    require_shaft(name, ctx.robot)
    return cls(ctx, **options)
