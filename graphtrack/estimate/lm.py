"""Levenberg-Marquardt over a gtsam graph, driven from Python.

Why not ``gtsam.LevenbergMarquardtOptimizer`` for a whole recording: inside
gtsam's optimizers the current Values is a C++ object that Python has never
seen, and pybind11 hands a COPY of it to every Python factor callback
(``gtsam.CustomFactor``). The copy is O(n) in the number of poses, so one
iteration over n frames costs O(n^2): measured with a trivial 6-residual
CustomFactor, 9 us per callback from ``graph.linearize(values)`` against
534 us inside ``GaussNewtonOptimizer.iterate`` at n = 1800. Here the Values
always belongs to Python, so the callbacks see it without a copy, and every
step is gtsam's own: ``graph.linearize``, the sparse multifrontal solve of
the damped linear system, ``Values.retract`` and ``graph.error``.

The iteration is gtsam's (``LevenbergMarquardtParams`` defaults): with the
linearisation J, b at x, solve

    (J^T J + lambda I) delta = J^T b       (as the extra rows sqrt(lambda) I per variable)

and accept x <- x (+) delta when the cost f (0.5 sum of squared whitened
errors) falls, rho = (f(x) - f(x (+) delta)) / (f(x) - l(delta)) > 1e-3
(l: the linearised cost); then lambda /= 10, otherwise lambda *= 10 and solve
again (stop once lambda > lambda_max). Converged when the relative decrease
(f_old - f_new) / f_old < relative_tolerance or f < absolute_tolerance.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

#: gtsam.LevenbergMarquardtParams' defaults
LAMBDA_INITIAL = 1e-5
LAMBDA_FACTOR = 10.0
LAMBDA_MAX = 1e5
MIN_MODEL_FIDELITY = 1e-3


@dataclass
class LMResult:
    values: object          # gtsam.Values at the optimum
    iterations: int         # accepted steps
    error: float            # final cost f
    linear_solves: int      # damped systems solved (accepted + rejected)


def levenberg_marquardt(graph, values, max_iterations: int = 30, relative_tolerance: float = 1e-3,
                        absolute_tolerance: float = 1e-5, lambda_initial: float = LAMBDA_INITIAL) -> LMResult:
    """Minimise ``graph``'s cost from ``values`` (gtsam objects: Pose3 and Vector
    variables; see the module docstring)."""
    dims = values.dims()   # per key: 6 for a Pose3, n for a length-n Vector
    error = graph.error(values)
    lam = float(lambda_initial)
    iterations = solves = 0
    blocks = {d: (gtsam.noiseModel.Unit.Create(d), np.zeros(d), np.eye(d)) for d in set(dims.values())}
    while iterations < max_iterations and error > absolute_tolerance:
        linear = graph.linearize(values)
        accepted = False
        while lam <= LAMBDA_MAX:
            damped = linear.clone()
            root = np.sqrt(lam)
            for k, d in dims.items():
                unit, zero, eye = blocks[d]
                damped.push_back(gtsam.JacobianFactor(k, root * eye, zero, unit))
            delta = damped.optimize()
            solves += 1
            predicted = error - linear.error(delta)
            candidate = values.retract(delta)
            new_error = graph.error(candidate)
            if predicted > 0 and (error - new_error) / predicted > MIN_MODEL_FIDELITY:
                accepted = True
                break
            lam *= LAMBDA_FACTOR
        if not accepted:
            break
        iterations += 1
        decrease = error - new_error
        values, error = candidate, new_error
        lam /= LAMBDA_FACTOR
        if decrease / max(error + decrease, 1e-300) < relative_tolerance:
            break
    return LMResult(values, iterations, float(error), solves)
