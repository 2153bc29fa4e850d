"""The particle filter on synthetic sequences (observations from the true geometry)."""
import numpy as np
import pytest

from graphtrack.detect.base import Observation
from graphtrack.estimate import make_estimator
from graphtrack.io.frame import Frame
from graphtrack.estimate.particle_filter import STD_COLUMNS, ParticleFilter
from graphtrack.estimate.pf.synthetic import make_scene, pose_error


def frame(scene, t):
    q = scene.joints(t)
    return Frame(t, t / 30.0, None, q[:6], q[6]), q


def run(pf, scene, model, frames, rng, hidden=(), **obs_kw):
    errs = []
    for t in frames:
        fr, q = frame(scene, t)
        obs = Observation(model) if t in hidden else scene.observation(q, model, rng, **obs_kw)
        est = pf.step(fr, obs)
        assert np.all(np.isfinite(est.E))
        errs.append(pose_error(est.E, scene.E_true))
    return np.array(errs)


@pytest.mark.parametrize("model", ["line-intensities-polar", "canny", "line-intensities"])
def test_converges_from_3mm_2deg(model):
    scene = make_scene(b_err=(0.003, 0.0, 0.0), w_err_deg=(0.0, 2.0, 0.0))
    assert pose_error(scene.ctx.handeye, scene.E_true)[1] == pytest.approx(2.0)
    pf = make_estimator("pf", scene.ctx, particles=1000, seed=0)
    errs = run(pf, scene, model, range(120), np.random.default_rng(0), pixel_noise=0.0, outliers=0.0)
    final = errs[-10:].mean(0)
    assert final[0] < 0.5 and final[1] < 0.25, final


def test_estimate_fields_and_determinism():
    scene = make_scene()
    out = []
    for _ in range(2):
        pf = ParticleFilter(scene.ctx, seed=3)
        fr, q = frame(scene, 0)
        est = pf.step(fr, scene.observation(q, "canny", np.random.default_rng(0)))
        out.append(est)
    np.testing.assert_array_equal(out[0].E, out[1].E)
    est = out[0]
    assert set(STD_COLUMNS) | {"ess"} <= set(est.extra)
    assert est.std.shape == (6,) and est.cov.shape == (6, 6)
    assert 1.0 <= est.extra["ess"] <= 1000
    np.testing.assert_allclose(est.E[3], [0, 0, 0, 1])
    np.testing.assert_allclose(est.E[:3, :3] @ est.E[:3, :3].T, np.eye(3), atol=1e-12)


def test_empty_frames_leave_weights_unchanged():
    scene = make_scene()
    pf = ParticleFilter(scene.ctx, seed=0)
    fr, q = frame(scene, 0)
    pf.step(fr, scene.observation(q, "line-intensities", np.random.default_rng(0)))
    before = pf.logw.copy()
    pf.step(fr, Observation("line-intensities"))
    np.testing.assert_array_equal(pf.logw, before)


def test_hidden_shaft_then_reacquire():
    scene = make_scene(b_err=(0.002, -0.001, 0.0), w_err_deg=(1.0, 0.0, -1.0))
    model = "line-intensities-polar"
    pf = ParticleFilter(scene.ctx, seed=1)
    rng = np.random.default_rng(1)
    a = run(pf, scene, model, range(80), rng)
    assert a[-1, 0] < 0.5
    hidden = set(range(80, 140))
    b = run(pf, scene, model, range(80, 140), rng, hidden=hidden)
    assert b.max(0)[0] < 1.5 and b.max(0)[1] < 0.6, b.max(0)  # no divergence while hidden
    c = run(pf, scene, model, range(140, 200), rng)
    assert c[29, 0] < 0.5 and c[29, 1] < 0.25, c[29]
    assert c[:, 0].max() < 2.0


def test_absurd_observations_never_kill_the_weights():
    scene = make_scene()
    pf = ParticleFilter(scene.ctx, seed=0)
    absurd = [Observation("line-intensities", pixels=[np.full((20, 2), 1e15)],
                          markers=np.array([[-1e9, 1e9]])),
              Observation("line-intensities", pixels=[np.array([[np.nan, np.inf]]), np.zeros((5, 2))]),
              Observation("canny", lines=np.array([[1e20, 1.0], [-3.0, 1e6]])),
              Observation("canny", lines=np.array([[np.nan, np.nan]]), markers=np.full((7, 2), 5.0))]
    for t, obs in enumerate(absurd * 3):
        fr, _ = frame(scene, t)
        est = pf.step(fr, obs)
        w = pf.weights
        assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0) and w.max() > 0
        assert np.all(np.isfinite(est.E)) and np.isfinite(est.extra["ess"])
