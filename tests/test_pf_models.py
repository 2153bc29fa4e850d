"""Observation models of the particle filter: the true pose must score best."""
import itertools
import numpy as np
import pytest

from graphtrack.detect.base import OBSERVATION_MODELS, POLAR_MODELS, Observation
from graphtrack.estimate import observation_models as om
from graphtrack.estimate.particle_filter import ParticleFilter
from graphtrack.geometry.lines import pixel_residual
from graphtrack.sim.synthetic import joint_trajectory, make_scene, observe

X_TRUE = np.r_[0.003, 0.0, 0.0, 0.0, np.radians(2.0), 0.0]   # hand-eye error (m, rad)
Q = joint_trajectory(91)


class World:
    """The synthetic world seen through E_true = Exp(X_TRUE) E_0 (markers as points)."""

    def __init__(self):
        s = make_scene()
        self.ctx, self.x_true, self.E_true = s.ctx, X_TRUE, s.true_E(X_TRUE)
        self.scene = s

    def joints(self, t):
        return Q[t]

    def observation(self, q, model, rng, markers=True, **kw):
        return observe(self.scene, q, self.E_true, rng, marker_model="point", **kw).observation(model, markers)


@pytest.fixture(scope="module")
def scene():
    return World()


def perturbed(x_true):
    """x_true and its 12 perturbations by +-1 mm / +-1 deg along each axis."""
    X = [x_true]
    for k in range(6):
        for sg in (1, -1):
            dx = np.zeros(6)
            dx[k] = sg * (1e-3 if k < 3 else np.radians(1.0))
            X.append(x_true + dx)
    return np.array(X)


@pytest.mark.parametrize("model", OBSERVATION_MODELS)
@pytest.mark.parametrize("t", [0, 90])
def test_true_pose_scores_highest(scene, model, t):
    rng = np.random.default_rng(t)
    q = scene.joints(t)
    obs = scene.observation(q, model, rng, pixel_noise=0.5, outliers=0.05,
                            line_noise=(0.2, 0.002), marker_noise=0.5)
    pf = ParticleFilter(scene.ctx)
    ll = pf.log_likelihood(q, obs, perturbed(scene.x_true))
    assert np.all(np.isfinite(ll))
    assert np.all(ll[0] > ll[1:]), ll - ll[0]


@pytest.mark.parametrize("model", ["line-intensities-polar", "line-intensities"])
def test_shaft_only_true_pose_not_worse(scene, model):
    """Without markers the lines leave motion along/about the shaft axis free:
    the truth still scores at least as well as every perturbation."""
    q = scene.joints(0)
    obs = scene.observation(q, model, np.random.default_rng(0), pixel_noise=0.0, outliers=0.0,
                            markers=False)
    pf = ParticleFilter(scene.ctx, markers=False)
    ll = pf.log_likelihood(q, obs, perturbed(scene.x_true))
    assert np.all(ll[0] >= ll[1:] - 1e-3)


def test_polar_pairing_is_order_free(scene):
    q = scene.joints(0)
    obs = scene.observation(q, "canny", np.random.default_rng(0))
    pf = ParticleFilter(scene.ctx, markers=False)
    h = pf.hypotheses(q, perturbed(scene.x_true))
    a = om.polar_loglik(h["rho"], h["theta"], obs.lines)
    b = om.polar_loglik(h["rho"], h["theta"], obs.lines[::-1])
    np.testing.assert_allclose(a, b)
    # the (-rho, theta + pi) form of a detected line is the same line
    flipped = obs.lines.copy()
    flipped[0] = (-flipped[0, 0], flipped[0, 1] + np.pi)
    np.testing.assert_allclose(om.polar_loglik(h["rho"], h["theta"], flipped), a, atol=1e-9)
    # edge_ids fix the pairing: the right ids agree with the best pairing at the truth
    ids = om.polar_loglik(h["rho"][:1], h["theta"][:1], obs.lines, edge_ids=np.array([0, 1]))
    np.testing.assert_allclose(ids, a[:1])
    # one detected line: scored against its better edge
    one = om.polar_loglik(h["rho"], h["theta"], obs.lines[1:])
    assert one[0] == pytest.approx(0.0, abs=1e-6)


def test_pixel_floor_bounds_a_stray_pixel(scene):
    """One far outlier costs at most c^2/2 nats (the robust floor)."""
    rho = np.array([[100.0, 200.0]])
    theta = np.array([[0.0, 0.0]])
    good = np.stack([np.full(50, 100.0), np.arange(50.0)], 1)
    stray = np.vstack([good, [[1e7, 5.0]]])
    a = om.pixel_loglik(rho, theta, good)
    b = om.pixel_loglik(rho, theta, stray)
    assert b[0] == pytest.approx(a[0] - om.PIXEL_OUTLIER_SIGMAS ** 2 / 2, rel=1e-5)


def test_markers_association_is_order_free_and_gated():
    rng = np.random.default_rng(0)
    proj = rng.uniform(0, 500, (50, 4, 2))
    vis = np.ones((50, 4), bool)
    det = proj[0, [2, 0, 3]] + 1.0
    a = om.marker_loglik(proj, vis, det)
    b = om.marker_loglik(proj, vis, det[::-1])
    np.testing.assert_allclose(a, b)
    assert a[0] == pytest.approx(-0.15 * 3 * np.sqrt(2))
    far = om.marker_loglik(proj, vis, np.array([[1e6, 1e6]]))
    np.testing.assert_allclose(far, -0.15 * om.MARKER_GATE)  # every particle: one outlier (cost at the gate)
    hidden = om.marker_loglik(proj, np.zeros((50, 4), bool), det)
    np.testing.assert_allclose(hidden, -0.15 * om.MARKER_GATE * 3)
    # more detections than model markers: unmatched ones are outliers
    many = om.marker_loglik(proj, vis, np.vstack([proj[0] + 0.0, [[1e5, 1e5]]]))
    assert many[0] == pytest.approx(-0.15 * om.MARKER_GATE)


def test_invalid_and_empty(scene):
    q = scene.joints(0)
    pf = ParticleFilter(scene.ctx)
    for model in OBSERVATION_MODELS:
        np.testing.assert_array_equal(pf.log_likelihood(q, Observation(model), perturbed(scene.x_true)), 0.0)
    rho = np.zeros((3, 2))
    theta = np.zeros((3, 2))
    valid = np.array([True, False, True])
    ll = om.shaft_loglik(Observation("canny", lines=np.array([[1.0, 0.0]])), rho, theta, valid)
    assert ll[1] == om.INVALID_LOGLIK and np.isfinite(ll).all()
    with pytest.raises(ValueError):
        om.shaft_loglik(Observation("nope", lines=np.ones((1, 2))), rho, theta, valid)


@pytest.mark.parametrize("model", ["canny", "line-intensities"])
def test_absurd_observations_stay_finite(scene, model):
    q = scene.joints(0)
    pf = ParticleFilter(scene.ctx)
    if model in POLAR_MODELS:
        obs = Observation(model, lines=np.array([[1e12, 7.0], [np.nan, 0.0], [-1e30, -1e9]]),
                          markers=np.array([[np.inf, 0], [1e9, -1e9]]))
    else:
        obs = Observation(model, pixels=[np.array([[1e30, -1e30], [np.nan, 1], [np.inf, 2]]),
                                         np.full((10, 2), 1e9)],
                          markers=np.array([[np.nan, 0], [1e12, 3]]))
    ll = pf.log_likelihood(q, obs)
    assert np.all(np.isfinite(ll))


def test_pixel_model_matches_per_pixel_formula():
    """Pruned float32 product against the plain float64 formula on the reference residual
    (:func:`graphtrack.geometry.lines.pixel_residual`), for tight clouds
    (most pixels scored against one edge), wide ones and a cloud wrapping theta."""
    rng = np.random.default_rng(5)
    sig, c = 2.0, 3.0
    for rho0, th0, spread_r, spread_t in [((300.0, 380.0), (0.7, 0.72), 1.0, 0.002),
                                          ((300.0, 380.0), (0.7, 0.72), 40.0, 0.3),
                                          ((50.0, 120.0), (0.001, 0.002), 2.0, 0.01)]:
        rho = np.array(rho0) + spread_r * rng.standard_normal((300, 2))
        theta = np.array(th0) + spread_t * rng.standard_normal((300, 2))
        rho = np.where(theta < 0, -rho, rho)
        theta = np.mod(theta, np.pi)
        t = rng.uniform(-400, 400, 200)
        pix = []
        for j in range(2):
            n = np.array([np.cos(th0[j]), np.sin(th0[j])])
            pix.append(rho0[j] * n + t[:, None] * [-n[1], n[0]] + rng.standard_normal((200, 1)) * n)
        pix = np.concatenate(pix + [rng.uniform(-500, 900, (40, 2))]) + [640, 512]
        rho = rho + np.cos(theta) * 640 + np.sin(theta) * 512
        w = rng.uniform(0.2, 1.0, len(pix))
        R = pixel_residual(pix[None, None], rho, theta)    # the reference residual, (300, 2, P)
        expect = -(np.minimum((R * R).min(axis=1), (c * sig) ** 2) * w).sum(axis=1) / (2 * sig * sig)
        got = om.pixel_loglik(rho, theta, pix, sig, c, pixel_weights=w)
        np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-2)


def test_marker_hungarian_fallback_matches_enumeration():
    rng = np.random.default_rng(3)
    proj = rng.uniform(0, 300, (20, 7, 2))
    vis = np.ones((20, 7), bool)
    det = proj[0, [1, 4, 6, 0]] + 0.5
    exact = om.marker_loglik(proj, vis, det)
    old = om.MAX_ENUMERATED
    om.MAX_ENUMERATED = 1
    try:
        hung = om.marker_loglik(proj, vis, det, estimate_index=0)
    finally:
        om.MAX_ENUMERATED = old
    assert hung[0] == pytest.approx(exact[0])
    assert np.all(hung <= exact + 1e-9)  # one shared assignment can only be worse


@pytest.mark.parametrize("n_det", [3, 5])
@pytest.mark.parametrize("loss", om.MARKER_LOSSES)
def test_marker_loglik_is_the_best_assignment_of_marker_cost(loss, n_det):
    # oracle: every injective pairing of the detections with 4 markers (a detection may stay
    # unpaired) enumerated by hand, each pair costing marker_cost(min(d, gate)); a marker
    # facing away, a NaN projection and an unpaired detection cost the gate's cost
    rng = np.random.default_rng(7)
    proj = rng.uniform(0, 200, (30, 4, 2))
    proj[3, 1] = np.nan
    vis = rng.uniform(size=(30, 4)) > 0.2
    det = np.concatenate([proj[0, :2] + [1.5, -2.0], rng.uniform(0, 200, (n_det - 3, 2)), [[500.0, 500.0]]])
    gate = 50.0
    cost = lambda d: float(om.marker_cost(np.float64(d), loss))   # noqa: E731
    expect = np.empty(30)
    for n in range(30):
        d = np.linalg.norm(det[:, None] - proj[n][None], axis=2)
        c = np.where(vis[n][None] & np.isfinite(d), np.minimum(d, gate), gate)
        options = [a for a in itertools.product([None, 0, 1, 2, 3], repeat=n_det)
                   if len([j for j in a if j is not None]) == len({j for j in a if j is not None})
                   and sum(j is not None for j in a) == min(n_det, 4)]
        expect[n] = -min(sum(cost(gate) if j is None else cost(c[k, j]) for k, j in enumerate(a)) for a in options)
    u0, v0 = proj[..., 0].copy(), proj[..., 1].copy()
    got = om.marker_loglik(proj, vis, det, gate=gate, loss=loss)
    np.testing.assert_allclose(got, expect, rtol=1e-12)
    np.testing.assert_array_equal(proj[..., 0], u0)   # the inputs are left as they were
    np.testing.assert_array_equal(proj[..., 1], v0)


def test_marker_losses_and_pixel_effective_count():
    d = np.array([0.0, 2.0, 4.0, 10.0, 100.0])
    np.testing.assert_allclose(om.marker_cost(d, "laplace", gamma=0.15), 0.15 * d)
    # huber, sigma 2, k 2: quadratic up to 4 px, then linear with slope k / sigma
    np.testing.assert_allclose(om.marker_cost(d, "huber", sigma=2.0, huber_k=2.0), [0, 0.5, 2.0, 2 * 5 - 2, 2 * 50 - 2])
    np.testing.assert_allclose(om.marker_cost(d, "cauchy", sigma=2.0), np.log1p((d / 2.0) ** 2))
    # laplace+cauchy: 2 px costs 0.3 + log 2, 10 px 1.5 + log 26
    np.testing.assert_allclose(om.marker_cost(d, "laplace+cauchy", gamma=0.15, sigma=2.0),
                               [0.0, 0.3 + np.log(2.0), 0.6 + np.log(5.0), 1.5 + np.log(26.0), 15.0 + np.log(2501.0)])
    with pytest.raises(ValueError):
        om.marker_cost(d, "nope")
    # gated: a far detection costs loss(gate) for every particle
    proj = np.random.default_rng(0).uniform(0, 500, (20, 4, 2))
    far = om.marker_loglik(proj, np.ones((20, 4), bool), np.array([[1e6, 1e6]]), gate=50.0, loss="huber")
    np.testing.assert_allclose(far, -(2.0 * 25.0 - 2.0))
    # effective count: an edge of m pixels is worth min(1, n / m) of its plain sum
    rho = np.array([[10.0, 200.0], [12.0, 200.0]])
    theta = np.zeros((2, 2))
    pix = np.stack([np.full(100, 11.0), np.arange(100.0)], 1)
    plain = om.pixel_loglik(rho, theta, pix)
    w = om.pixel_loglik(rho, theta, pix, pixel_weights=np.full(100, 0.1))
    np.testing.assert_allclose(w, 0.1 * plain, rtol=1e-5)
    obs = Observation("line-intensities", pixels=[pix])
    s = om.shaft_loglik(obs, rho, theta, np.ones(2, bool), pixel_effective_count=10.0)
    np.testing.assert_allclose(s, 0.1 * plain, rtol=1e-5)


def test_a_band_counts_band_weight_times_a_refined_set():
    """shaft_loglik is a weighted sum over pixels (module formula): with one set marked
    a band, the frame scores loglik(refined set) + band_weight * loglik(band), each set
    scored alone with the same effective count (hand-derived from the sum's linearity).
    Unmarked observations (bands empty) and band_weight 1 score as before."""
    rng = np.random.default_rng(7)
    rho = np.array([[300.0, 420.0]]) + rng.normal(0.0, 3.0, (50, 2))
    theta = np.full((50, 2), 0.6) + rng.normal(0.0, 0.01, (50, 2))
    sets = []
    for r0 in (300.0, 424.0):   # the second set lies 4 px off its limb, as an outward band
        n = np.array([np.cos(0.6), np.sin(0.6)])
        sets.append(r0 * n + np.linspace(-200, 200, 80)[:, None] * [-n[1], n[0]])
    valid = np.ones(50, bool)

    def ll(pixels, bands=(), **kw):
        obs = Observation("line-intensities", pixels=pixels, bands=np.array(bands, bool))
        return om.shaft_loglik(obs, rho, theta, valid, **kw)

    alone = [ll([p]) for p in sets]
    both = ll(sets, [False, True], band_weight=0.25)
    np.testing.assert_allclose(both, alone[0] + 0.25 * alone[1], rtol=1e-5)
    np.testing.assert_allclose(ll(sets), alone[0] + alone[1], rtol=1e-5)
    np.testing.assert_allclose(ll(sets, [False, True]), ll(sets), rtol=1e-12)   # default weight 1


def test_the_band_weight_reaches_the_particle_filters_search_and_not_the_smoothers(scene):
    """The particle filter scores bands at BAND_WEIGHT in its likelihood and in its
    start-up search; the smoother's search keeps 1 (docs/decisions/band-weight.md)."""
    from graphtrack.estimate.smoother import FixedLagSmootherEstimator
    from graphtrack.sim.synthetic import sequence

    ctx = sequence(2, seed=0, scene=make_scene()).ctx
    pf = ParticleFilter(ctx, particles=10)
    assert pf.shaft_options["band_weight"] == om.BAND_WEIGHT == 0.25
    assert pf.search.scorer.shaft_options["band_weight"] == om.BAND_WEIGHT
    assert FixedLagSmootherEstimator(ctx).reinit.scorer.shaft_options["band_weight"] == 1.0
