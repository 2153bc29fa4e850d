"""The Python-driven Levenberg-Marquardt against gtsam's own optimizer on the same graph."""
import gtsam
import numpy as np

from graphtrack.sim.synthetic import make_scene, sequence
from graphtrack.detect.base import Observation
from graphtrack.io.frame import Frame
from graphtrack.estimate.batch import BatchEstimator
from graphtrack.io.context import TrackingContext
from graphtrack.estimate.lm import levenberg_marquardt


def _graph(n=40, seed=3):
    robot, cam, E0, frames = sequence(n, seed=seed, scene=make_scene(), walk_sigma=(2.5e-5, 1e-4),
                                      pixel_noise=1.5, marker_noise=2.0, pixels_per_edge=80)
    est = BatchEstimator(TrackingContext(robot, cam, E0), provisional="last")
    for f in frames:
        est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]),
                 Observation("line-intensities", pixels=f.pixels, markers=f.markers))
    return est.build()


def test_matches_gtsam_levenberg_marquardt():
    graph, values = _graph()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-9)
    params.setAbsoluteErrorTol(0.0)
    ref = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    res = levenberg_marquardt(graph, values, max_iterations=50, relative_tolerance=1e-9, absolute_tolerance=0.0)
    assert res.iterations > 1
    assert abs(res.error - graph.error(ref)) <= 1e-8 * graph.error(ref)
    kinds = {chr(gtsam.Symbol(k).chr()) for k in values.keys()}
    assert kinds == {"x", "b"}          # poses and the edge-bias vectors (px)
    for k in values.keys():
        if chr(gtsam.Symbol(k).chr()) == "x":
            d = gtsam.Pose3.Logmap(ref.atPose3(k).between(res.values.atPose3(k)))
        else:
            d = 1e-3 * (ref.atVector(k) - res.values.atVector(k))
        assert np.max(np.abs(d)) < 1e-7, (k, d)


def test_pure_gtsam_graph_reaches_the_known_optimum():
    """Priors only: the optimum of each pose is its prior mean (hand-checkable)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    rng = np.random.default_rng(0)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    means = []
    for k in range(5):
        m = gtsam.Pose3.Expmap(rng.normal(scale=0.3, size=6))
        means.append(m)
        graph.add(gtsam.PriorFactorPose3(k, m, noise))
        values.insert(k, gtsam.Pose3())
    res = levenberg_marquardt(graph, values, relative_tolerance=1e-12, absolute_tolerance=1e-20)
    for k, m in enumerate(means):
        assert np.allclose(res.values.atPose3(k).matrix(), m.matrix(), atol=1e-8)
    assert res.error < 1e-16
