"""GTSAM factors tying one frame's detections to the lumped error E_t (a gtsam.Pose3).

Every measurement factor is a ``gtsam.CustomFactor`` on ONE Pose3 key E
(camera-from-base; the shaft-pixel factor also on the frame's edge-bias vector
when that state is used) whose error function is a small, typed, vectorised
numpy function with an ANALYTIC Jacobian in GTSAM's right (body) perturbation
convention

    E (+) xi = E . Exp(xi),      xi = (omega, v)   (rotation first, as gtsam)

- :mod:`factors.shaft_pixels`: point-to-projected-line residuals of one shaft
  edge's pixel set (pixel observation models);
- :mod:`factors.line_parameter`: (rho, theta) of one detected shaft line
  (polar observation models), angle wrapped;
- :mod:`factors.marker`: reprojection of the painted markers (points, or discs
  on the shaft: the centroid of their image) with Hungarian association and a
  gate;
- :mod:`factors.robust`: the Huber / Cauchy kernels (gtsam's mEstimator
  definitions), applied per pixel / per marker inside the multi-residual factors;
- :mod:`factors.edge_bias`: the detector's edge-bias state (lateral / width
  offset and slope, px) and its Gauss-Markov prior and transition;
- :mod:`factors.limb`: the pairing of a frame's shaft observations with the two
  limbs (the limb lines and their derivatives are
  :func:`graphtrack.geometry.cylinder.limb_line_coefficients`).

The noise values, gates and robust kernels have no defaults here: the caller
passes them (the smoother and the batch from
:class:`graphtrack.estimate.graph.FactorOptions`, where each is written once).

Synthetic observations for their tests: :mod:`graphtrack.sim.synthetic`.
"""
from factors.robust import RobustKernel, make_kernel  # noqa: F401
