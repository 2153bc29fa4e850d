"""Robust online tracking (issue #18): the motion prior through a stretch without
detections, covariance-following marker gates, and the divergence monitor's
false-alarm rate and detection delay, on the synthetic observation world
(graphtrack.sim.synthetic through tests/robust_world.py: observations from the true geometry)."""
import numpy as np
import pytest

from graphtrack.detect.base import Observation
from graphtrack.estimate import make_estimator
from graphtrack.estimate.divergence import NOMINAL_FALSE_ALARM_RATE, DivergenceMonitor
from graphtrack.estimate.gating import CEIL_PX, N_SIGMA_2D, marker_gate
from robust_world import make_world as make_scene
from graphtrack.estimate.startup import Scorer
from graphtrack.eval.robustness import no_detection_stretches
from graphtrack.geometry.se3 import bw_to_matrix
from graphtrack.io.frame import Frame
from graphtrack.robot.features import base_features

MODEL = "line-intensities"


def _run_blank(name, blank=(15, 55), frames=60):
    """Track the synthetic world with no detections over ``blank``; the estimates' std
    (frames, 6), poses (frames, 4, 4) and, for the particle filter, its particles per frame."""
    scene = make_scene(seed=7, b_mm=3.0, w_deg=1.5)
    est = make_estimator(name, scene.ctx, **({"particles": 400} if name == "pf" else {}))
    stds, poses, clouds = [], [], []
    for t in range(frames):
        q = scene.joints(t)
        obs = (Observation(MODEL) if blank[0] <= t < blank[1] else
               scene.observation(q, MODEL, np.random.default_rng(t), pixel_noise=0.5, outliers=0.02))
        e = est.step(Frame(t, t / 30.0, None, q[:6], q[6]), obs)
        stds.append(np.asarray(e.std, float))
        poses.append(e.E)
        clouds.append(est.x.copy() if name == "pf" else None)
    return est, np.array(stds), np.array(poses), clouds


@pytest.mark.parametrize("name", ["pf", "smoother"])
def test_std_grows_over_a_blanked_stretch_and_no_pose_is_nan(name):
    """Oracle: with no measurement a random walk's variance grows by n sigma_motion^2
    over n frames. The smoother's marginal shows it (half of it allowed for the frame
    change); a particle cloud far wider than sigma_motion along some axis cannot show
    2e-7 rad^2 in its sample covariance, so for the particle filter the oracle is each
    particle's own displacement: no weight changes without detections, so nothing is
    resampled and x_n(t) - x_n(a) ~ N(0, (t - a) sigma^2) per axis."""
    a, b = 15, 55
    est, std, poses, clouds = _run_blank(name, (a, b))
    assert np.all(np.isfinite(poses)) and np.all(np.isfinite(std))
    sig = np.array([2.5e-5] * 3 + [1e-4] * 3)           # both estimators' default motion stds
    if name == "smoother":
        grown = std[b - 1] ** 2 - std[a - 1] ** 2
        assert np.all(grown > 0.5 * (b - a) * sig ** 2), (grown, (b - a) * sig ** 2)
        # and it grows along the stretch, not only at its end
        assert np.all(std[a + 20] ** 2 - std[a - 1] ** 2 > 0.5 * 21 * sig ** 2)
    else:
        for n in (20, b - 1 - a):
            ratio = np.var(clouds[a + n] - clouds[a], axis=0) / (n * sig ** 2)
            np.testing.assert_allclose(ratio, 1.0, atol=0.25)   # 400 particles: ~7 % sampling error
    # the pose during the stretch is the motion prior: it stays where it was (no jump)
    moved = np.linalg.norm(poses[a:b, :3, 3] - poses[a - 1, :3, 3], axis=1)
    assert np.max(moved) < 2e-3


def test_no_detection_stretches_are_reported():
    frames = list(range(100, 160))
    informative = [True] * 10 + [False] * 20 + [True] * 5 + [False] * 5 + [True] * 2 + [False] * 18
    assert no_detection_stretches(frames, informative, min_frames=15) == [[110, 130], [142, 160]]
    assert no_detection_stretches(frames, informative, min_frames=21) == []
    assert no_detection_stretches([], [], 1) == []


def _mc_gate(points, K, C, sigma, n=20000, seed=0):
    """Monte-Carlo oracle: 3 x the largest principal std of the projected markers under
    samples E = Exp(x) E, x ~ N(0, C), with the detection noise added."""
    rng = np.random.default_rng(seed)
    xs = rng.multivariate_normal(np.zeros(6), C, n)
    out = 0.0
    for X in points:
        proj = []
        for x in xs[:4000]:
            E = bw_to_matrix(x)
            Y = E[:3, :3] @ X + E[:3, 3]
            proj.append(K[:2, :2] @ (Y[:2] / Y[2]))
        P = np.cov(np.array(proj).T)
        out = max(out, 3 * np.sqrt(np.linalg.eigvalsh(P)[-1] + sigma ** 2))
    return out


def test_marker_gate_follows_the_covariance():
    scene = make_scene(seed=3, b_mm=0.0, w_deg=0.0)
    K = scene.ctx.camera.K
    points = base_features(scene.ctx.robot, scene.joints(0)).transformed(scene.E_true).points
    points = points[points[:, 2] > 0]
    configured = 60.0
    # unusable covariance: the configured gate
    assert marker_gate(points, K, None, configured, 2.0) == configured
    assert marker_gate(points, K, np.full((6, 6), np.nan), configured, 2.0) == configured
    # confident: the configured gate (or a floor given); very uncertain: the ceiling (detection px x scale)
    assert marker_gate(points, K, np.eye(6) * 1e-14, configured, 2.0, scale=2.0) == configured
    assert marker_gate(points, K, np.eye(6) * 1e-14, configured, 2.0, scale=2.0, floor=20) == pytest.approx(40)
    assert marker_gate(points, K, np.eye(6) * 1e-2, configured, 2.0, scale=2.0) == pytest.approx(2 * CEIL_PX)
    # in between it matches the Monte-Carlo spread of the predicted markers and grows with C
    C = np.diag([1.5e-3] * 3 + [0.01] * 3) ** 2
    g = marker_gate(points, K, C, configured, 2.0, floor=0, ceil=1e9)
    assert g == pytest.approx(_mc_gate(points, K, C, 2.0), rel=0.1)
    assert marker_gate(points, K, 4 * C, configured, 2.0, floor=0, ceil=1e9) > 1.8 * g


@pytest.mark.parametrize("name", ["pf", "smoother"])
def test_marker_gate_widens_after_a_gap_and_returns_as_it_converges(name):
    """With marker_gate_follows_covariance the estimators' gate follows their
    covariance. The particle filter's: wide while uncertain (its initial cloud), back to
    the configured gate once confident, never below it. The smoother's: the configured
    gate until it has a covariance, then narrower as it converges (gating.smoother_gate),
    never above the configured gate nor below 3.72 marker sigmas."""
    scene = make_scene(seed=2, b_mm=3.0, w_deg=1.5)
    est = make_estimator(name, scene.ctx, search=False, marker_gate_follows_covariance=True,
                         **({"particles": 400} if name == "pf" else {}))
    configured = est.configured_gate if name == "pf" else est.fopts.marker_gate * est.fopts.gate_scale

    def gate(q, obs):
        if name == "pf":
            est._gate_markers(q)
            return est.marker_gate
        o = est._gated_options(base_features(scene.ctx.robot, q), obs)
        return o.marker_gate * o.gate_scale

    gates = []
    for t in range(40):
        q = scene.joints(t)
        obs = scene.observation(q, MODEL, np.random.default_rng(t), pixel_noise=0.5, outliers=0.02)
        gates.append(gate(q, obs))
        est.step(Frame(t, t / 30.0, None, q[:6], q[6]), obs)
    if name == "pf":
        assert min(gates) >= configured
        assert gates[-1] == pytest.approx(configured)      # confident
        assert gates[0] > configured                       # the initial cloud
    else:
        floor = N_SIGMA_2D * est.fopts.marker_sigma
        assert gates[0] == pytest.approx(configured)       # no covariance yet
        assert max(gates) <= configured + 1e-9 and min(gates) >= floor - 1e-9
        assert gates[-1] < 0.5 * configured                # confident


def _monitor_run(scene, x_of_t, frames, seed, pixel_noise=1.0, outliers=0.05):
    scorer, mon = Scorer(scene.ctx), DivergenceMonitor()
    rng = np.random.default_rng(seed)
    fired_at = []
    for t in range(frames):
        q = scene.joints(t)
        obs = scene.observation(q, MODEL, rng, pixel_noise=pixel_noise, outliers=outliers,
                                marker_noise=1.0)
        x = x_of_t(t, rng)
        if mon.update(float(scorer(q, obs, x[None])[0]), scorer.floor(q, obs, x)):
            fired_at.append(t)
    return fired_at


@pytest.mark.slow
@pytest.mark.parametrize("name", ["pf", "smoother"])
def test_monitor_false_alarm_rate_under_nominal_on_consistent_data(name):
    """The tracker itself on consistent data (noisy pixels with 10 % outliers, noisy
    markers, the truth drifting by the motion model): its monitor's alarms per
    informative frame stay under the nominal rate over seeds x frames."""
    alarms = frames = 0
    for seed in range(3):
        scene = make_scene(seed=20 + seed, b_mm=3.0, w_deg=1.5)
        est = make_estimator(name, scene.ctx, **({"particles": 300, "seed": seed} if name == "pf" else {}))
        policy = est.search if name == "pf" else est.reinit
        rng = np.random.default_rng(seed)
        walk = np.array([2.5e-5] * 3 + [1e-4] * 3)
        for t in range(100):
            scene.E_true = bw_to_matrix(walk * rng.standard_normal(6)) @ scene.E_true
            q = scene.joints(t)
            est.step(Frame(t, t / 30.0, None, q[:6], q[6]),
                     scene.observation(q, MODEL, rng, pixel_noise=1.5, outliers=0.1, marker_noise=1.0))
        alarms += policy.monitor.fired
        frames += 100
    assert alarms / frames < NOMINAL_FALSE_ALARM_RATE, (alarms, frames)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_monitor_fires_soon_on_a_wrong_lock(seed):
    """A lock on the wrong pairing (4 mm / 1.7 deg off): the first alarm within two windows."""
    scene = make_scene(seed=30 + seed, b_mm=4.0, w_deg=2.0)
    wrong = scene.x_true + np.array([0.004, -0.003, 0, 0, 0.03, 0])
    fired = _monitor_run(scene, lambda t, r: wrong, 40, seed)
    assert fired and fired[0] < 2 * DivergenceMonitor().window, fired
