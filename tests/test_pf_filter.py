"""The particle filter on synthetic sequences (observations from the true geometry)."""
import numpy as np
import pytest

from graphtrack.detect.base import Observation
from graphtrack.estimate import make_estimator
from graphtrack.io.frame import Frame
from graphtrack.estimate.particle_filter import STD_COLUMNS, ParticleFilter
from graphtrack.sim.synthetic import joint_trajectory, make_scene, observe, pose_error

SCENE = make_scene()
Q = joint_trajectory(200)


class World:
    """The synthetic world with the hand-eye error x_true = (b m, w rad): E_true = Exp(x_true) E_0."""

    def __init__(self, b=(0.003, 0.0, 0.0), w_deg=(0.0, 2.0, 0.0)):
        self.x_true = np.r_[b, np.radians(w_deg)]
        self.E_true = SCENE.true_E(self.x_true)
        self.ctx = SCENE.ctx

    def observation(self, t, model, rng, markers=True, marker_model="disc", **kw):
        """Frame t seen through E_true; the markers painted discs (the blobs' centroids,
        which the filter moves to the discs' centres) or, with ``marker_model="point"``,
        the centres' projections (the paper's point markers)."""
        kw = {"outliers": 0.05, **kw}
        return observe(SCENE, Q[t], self.E_true, rng, marker_model=marker_model, **kw).observation(model, markers)


def frame(t):
    return Frame(t, t / 30.0, None, Q[t, :6], Q[t, 6])


def run(pf, world, model, frames, rng, hidden=(), **obs_kw):
    errs = []
    for t in frames:
        obs = Observation(model) if t in hidden else world.observation(t, model, rng, **obs_kw)
        est = pf.step(frame(t), obs)
        assert np.all(np.isfinite(est.E))
        errs.append(pose_error(est.E, world.E_true))
    return np.array(errs)


@pytest.mark.parametrize("model", ["line-intensities-polar", "canny", "line-intensities"])
def test_converges_from_3mm_2deg(model):
    world = World(b=(0.003, 0.0, 0.0), w_deg=(0.0, 2.0, 0.0))
    assert pose_error(world.ctx.handeye, world.E_true)[1] == pytest.approx(2.0)
    pf = make_estimator("pf", world.ctx, particles=1000, seed=0)
    errs = run(pf, world, model, range(120), np.random.default_rng(0), pixel_noise=0.0, outliers=0.0)
    final = errs[-10:].mean(0)
    assert final[0] < 0.5 and final[1] < 0.25, final


def test_point_markers_converge_with_the_disc_model_off():
    """The paper's filter: point-marker detections, scored as they are (``marker_discs`` off)."""
    world = World(b=(0.003, 0.0, 0.0), w_deg=(0.0, 2.0, 0.0))
    pf = make_estimator("pf", world.ctx, particles=1000, seed=0, marker_discs=False)
    errs = run(pf, world, "line-intensities", range(120), np.random.default_rng(0), pixel_noise=0.0,
               outliers=0.0, marker_model="point")
    final = errs[-10:].mean(0)
    assert final[0] < 0.5 and final[1] < 0.25, final


def test_estimate_fields_and_determinism():
    world = World()
    out = []
    for _ in range(2):
        pf = ParticleFilter(world.ctx, seed=3)
        est = pf.step(frame(0), world.observation(0, "canny", np.random.default_rng(0)))
        out.append(est)
    np.testing.assert_array_equal(out[0].E, out[1].E)
    est = out[0]
    assert set(STD_COLUMNS) | {"ess"} <= set(est.extra)
    assert est.std.shape == (6,) and est.cov.shape == (6, 6)
    assert 1.0 <= est.extra["ess"] <= 1000
    np.testing.assert_allclose(est.E[3], [0, 0, 0, 1])
    np.testing.assert_allclose(est.E[:3, :3] @ est.E[:3, :3].T, np.eye(3), atol=1e-12)


def test_empty_frames_leave_weights_unchanged():
    world = World()
    pf = ParticleFilter(world.ctx, seed=0)
    pf.step(frame(0), world.observation(0, "line-intensities", np.random.default_rng(0)))
    before = pf.logw.copy()
    pf.step(frame(0), Observation("line-intensities"))
    np.testing.assert_array_equal(pf.logw, before)


def test_hidden_shaft_then_reacquire():
    world = World(b=(0.002, -0.001, 0.0), w_deg=(1.0, 0.0, -1.0))
    model = "line-intensities-polar"
    pf = ParticleFilter(world.ctx, seed=1)
    rng = np.random.default_rng(1)
    a = run(pf, world, model, range(80), rng)
    assert a[-1, 0] < 0.5
    hidden = set(range(80, 140))
    b = run(pf, world, model, range(80, 140), rng, hidden=hidden)
    assert b.max(0)[0] < 1.5 and b.max(0)[1] < 0.6, b.max(0)  # no divergence while hidden
    c = run(pf, world, model, range(140, 200), rng)
    assert c[29, 0] < 0.5 and c[29, 1] < 0.25, c[29]
    assert c[:, 0].max() < 2.0


def test_absurd_observations_never_kill_the_weights():
    pf = ParticleFilter(SCENE.ctx, seed=0)
    absurd = [Observation("line-intensities", pixels=[np.full((20, 2), 1e15)],
                          markers=np.array([[-1e9, 1e9]])),
              Observation("line-intensities", pixels=[np.array([[np.nan, np.inf]]), np.zeros((5, 2))]),
              Observation("canny", lines=np.array([[1e20, 1.0], [-3.0, 1e6]])),
              Observation("canny", lines=np.array([[np.nan, np.nan]]), markers=np.full((7, 2), 5.0))]
    for t, obs in enumerate(absurd * 3):
        est = pf.step(frame(t), obs)
        w = pf.weights
        assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0) and w.max() > 0
        assert np.all(np.isfinite(est.E)) and np.isfinite(est.extra["ess"])


def test_roughening_keeps_the_clouds_mean_and_covariance():
    """Kernel shrinkage (Liu & West): after resampling and roughening the cloud has the
    weighted mean and covariance it had before (in expectation); jitter alone would
    inflate the covariance by 1 + h^2 = 1.25 at h = 0.5."""
    n = 40000
    pf = ParticleFilter(SCENE.ctx, particles=n, seed=0, search=False, roughening=0.5)
    rng = np.random.default_rng(5)
    scale = np.array([1e-3, 5e-4, 2e-3, 4e-3, 2e-3, 1e-2])   # inside the prior spread (no cap)
    pf.x = rng.standard_normal((n, 6)) * scale + 1e-3
    logw = -0.5 * np.sum(((pf.x - 1e-3) / (1.5 * scale)) ** 2, axis=1)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    mean = w @ pf.x
    cov = ((pf.x - mean) * w[:, None]).T @ (pf.x - mean)
    pf.resample(w, cov)
    after = pf.x.mean(axis=0)
    assert np.all(np.abs(after - mean) < 0.05 * np.sqrt(np.diag(cov))), (after - mean) / np.sqrt(np.diag(cov))
    ratio = np.var(pf.x, axis=0) / np.diag(cov)
    np.testing.assert_allclose(ratio, 1.0, atol=0.05)
