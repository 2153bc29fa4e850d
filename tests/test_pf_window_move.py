"""The particle filter's window move (graphtrack/estimate/pf/window_move.py)."""
from dataclasses import replace

import numpy as np

from graphtrack.estimate.particle_filter import ParticleFilter
import graphtrack.estimate.pf.window_move as window_move
from graphtrack.estimate.pf.window_move import MIN_GAIN, SCHEDULE, WIDE_MARGIN, window_mode, move_target
from graphtrack.io.frame import Frame
from graphtrack.sim.synthetic import joint_trajectory, make_scene, observe

SCENE = make_scene()
Q = joint_trajectory(40)


def quadratic(mode, scale):
    """log-likelihood -1/2 sum(((x - mode) / scale)^2): with a flat prior (spread 1e9) its
    mode and every gain are known by hand."""
    mode, scale = np.asarray(mode, float), np.asarray(scale, float)
    return lambda X: -0.5 * np.sum(((np.atleast_2d(X) - mode) / scale) ** 2, axis=1)


def test_the_search_finds_a_mode_several_cloud_spreads_away():
    scale = np.array([1e-3, 1e-3, 4e-3, 0.01, 0.01, 0.01])
    mode = np.array([0.0, 0.0, 3e-3, 0.0, 0.0, 0.0])           # 3 mm along z, a flat-ish axis
    J = quadratic(mode, scale)
    res = window_mode(J, np.zeros(6), cloud_cov=np.diag(np.full(6, 1e-4) ** 2), floor=np.array([1e-3] * 3 + [7e-3] * 3),
                      prior_spread=np.full(6, 1e9), rng=np.random.default_rng(0))
    # J(0) = -1/2 (3/4)^2 = -0.28125 by hand; the mode scores 0
    assert abs(res.x[2] - 3e-3) < 0.6e-3
    assert 0.2 < res.gain <= 0.28125 + 1e-12


def test_the_search_walks_along_the_valley_the_cloud_spans():
    """A valley along d = (b_y, w_x) / |.| (the slide / tilt ridge of a shaft seen from
    the side): J(x) = -1/2 [((x - m) . d / 5 mm)^2 + |(x - m) - ((x - m) . d) d|^2 / (0.05 mm)^2],
    its mode m 4 mm along d from the cloud's mean (four of the cloud's 1 mm spreads along d;
    0.05 mm across it). By hand J(0) = -1/2 (4 / 5)^2 = -0.32 and J(m) = 0: the search,
    drawn along the cloud and walking over its stages, finds m and the gain 0.32 whatever
    its seed."""
    d = np.zeros(6)
    d[1], d[3] = 1.0, 1.0
    d /= np.linalg.norm(d)
    m = 4e-3 * d
    along, across = 5e-3, 5e-5

    def J(X):
        r = np.atleast_2d(X) - m
        t = r @ d
        return -0.5 * ((t / along) ** 2 + np.sum((r - t[:, None] * d) ** 2, axis=1) / across ** 2)

    cov = (1e-3) ** 2 * np.outer(d, d) + across ** 2 * (np.eye(6) - np.outer(d, d))
    for seed in range(5):
        res = window_mode(J, np.zeros(6), cov, np.full(6, 1e-5), np.full(6, 1e9), np.random.default_rng(seed))
        assert np.linalg.norm(res.x - m) < 0.5e-3, seed
        assert 0.3 < res.gain <= 0.32 + 1e-9, seed


def test_a_cloud_at_the_mode_gains_nothing():
    scale = np.full(6, 1e-3)
    res = window_mode(quadratic(np.zeros(6), scale), np.zeros(6), np.diag(np.full(6, 1e-4) ** 2), np.full(6, 1e-3),
                      np.full(6, 1e9), np.random.default_rng(1))
    assert res.gain == 0.0
    np.testing.assert_array_equal(res.x, np.zeros(6))


def _frames(E, n, rng):
    out = []
    for t in range(n):
        obs = observe(SCENE, Q[t], E, rng, pixel_noise=0.3, outliers=0.0)
        out.append((Frame(t, t / 30.0, None, Q[t, :6], Q[t, 6]), obs.observation("line-intensities", True)))
    return out


def test_the_cloud_is_shifted_whole_to_a_clearly_better_mode():
    """A cloud started 3 mm off the true E, too narrow to reach it by resampling, is moved
    onto it after SCHEDULE[0] frames; its particles keep their offsets from the mean."""
    x_true = np.r_[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    frames = _frames(SCENE.true_E(x_true), SCHEDULE[0], np.random.default_rng(0))
    pf = ParticleFilter(SCENE.ctx, particles=300, seed=0, search=False, window_move=True,
                        init_std_b=2e-4, init_std_w=1e-3)
    pf.reset(np.r_[0.0, 3e-3, 0.0, 0.0, 0.0, 0.0])
    for fr, obs in frames[:-1]:
        pf.step(fr, obs)
    seen = []
    original = pf._move

    def move():
        before = pf.x.copy()
        moved = original()
        seen.append((moved, pf.x - before))
        return moved

    pf._move = move
    est = pf.step(*frames[-1])
    assert [m for m, _ in seen] == [True] and pf.window_moves == 1
    shift = seen[0][1]
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-12)   # rigid
    assert np.linalg.norm(est.E[:3, 3] - SCENE.true_E(x_true)[:3, 3]) < 1e-3


def test_no_move_without_a_clear_gain():
    x_true = np.zeros(6)
    frames = _frames(SCENE.true_E(x_true), SCHEDULE[0], np.random.default_rng(0))
    pf = ParticleFilter(SCENE.ctx, particles=300, seed=0, search=False, init_std_b=2e-4, init_std_w=1e-3)
    pf.reset(x_true)
    for fr, obs in frames:
        pf.step(fr, obs)
    assert pf.window_moves == 0


def test_switched_off_it_leaves_the_filter_as_it_was():
    frames = _frames(SCENE.true_E(np.zeros(6)), SCHEDULE[0], np.random.default_rng(0))
    runs = []
    for on in (True, False):
        pf = ParticleFilter(SCENE.ctx, particles=200, seed=0, search=False, window_move=on)
        runs.append([pf.step(fr, obs).E for fr, obs in frames[:-1]])
    np.testing.assert_array_equal(np.array(runs[0]), np.array(runs[1]))   # before the schedule: the same draws
    assert MIN_GAIN == 3.0


def test_nothing_scored_means_no_move():
    res = window_mode(lambda X: np.full(len(np.atleast_2d(X)), -np.inf), np.zeros(6), np.diag(np.full(6, 1e-4) ** 2),
                      np.full(6, 1e-3), np.full(6, 1e-2), np.random.default_rng(0))
    assert res.gain == -np.inf and not res.gain > MIN_GAIN
    np.testing.assert_array_equal(res.x, np.zeros(6))
    # a degenerate cloud (non-finite covariance) is not searched: no move, no exception
    res = window_mode(lambda X: np.zeros(len(np.atleast_2d(X))), np.zeros(6), np.full((6, 6), np.nan),
                      np.full(6, 1e-3), np.full(6, 1e-2), np.random.default_rng(0))
    assert res.gain == -np.inf


def _plateau(frames, floor, mode, width=1.5e-3):
    """The window's summed log-likelihood of a likelihood at its outlier floor (``floor``
    nats per frame, the same everywhere) except within ``width`` of ``mode`` in b, where it
    rises to 0: far from the mode it is flat, no search along the cloud sees it."""
    def loglik(X):
        r = np.linalg.norm(np.atleast_2d(X)[:, :3] - mode[:3], axis=1) / width
        return frames * np.maximum(floor, -0.5 * r ** 2)
    return loglik


SPREAD = np.array([6e-3] * 3 + [0.05] * 3)        # the search's prior spread (m, rad)
CLOUD = np.diag(np.r_[np.full(3, 3e-4), np.full(3, 2e-3)] ** 2)
FLOOR = np.r_[np.full(3, 1e-3), np.full(3, 7.5e-3)]


def test_a_mode_beyond_the_clouds_reach_is_found_over_the_prior():
    """The cloud at 0, the window's mode 12 mm away behind a flat floor of -6 nats per frame
    over 8 frames: by hand the gain is 8 x 6 - 1/2 (12/6)^2 = 46 nats > 8 x WIDE_MARGIN = 40,
    so the target is the mode (the search around the cloud finds nothing, the floor is flat)."""
    mode = np.r_[12e-3, 0.0, 0.0, 0.0, 0.0, 0.0]
    J = _plateau(8, -6.0, mode)
    near = window_mode(J, np.zeros(6), CLOUD, FLOOR, SPREAD, np.random.default_rng(0))
    assert not near.gain > MIN_GAIN
    for seed in range(5):
        x = move_target(J, 8, np.zeros(6), CLOUD, FLOOR, SPREAD, np.random.default_rng(seed)).x
        assert x is not None and np.linalg.norm(x[:3] - mode[:3]) < 1e-3, seed


def test_a_wide_mode_must_beat_the_margin_per_frame():
    """The same mode behind a floor of -4 nats per frame: the gain, 8 x 4 - 2 = 30 nats, is
    under 8 x WIDE_MARGIN: no target. And with the wide search off (WIDE_MARGIN None), not
    even the clear mode above is taken."""
    assert WIDE_MARGIN == 5.0
    mode = np.r_[12e-3, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert move_target(_plateau(8, -4.0, mode), 8, np.zeros(6), CLOUD, FLOOR, SPREAD,
                         np.random.default_rng(0)).x is None
    try:
        window_move.WIDE_MARGIN = None
        assert move_target(_plateau(8, -6.0, mode), 8, np.zeros(6), CLOUD, FLOOR, SPREAD,
                             np.random.default_rng(0)).x is None
    finally:
        window_move.WIDE_MARGIN = WIDE_MARGIN


def test_a_mode_near_the_cloud_is_taken_at_the_small_gain():
    """A quadratic mode 1 mm from the cloud with the gain 4 nats by hand (> MIN_GAIN, far
    under 8 x WIDE_MARGIN): the search around the cloud takes it."""
    mode = np.r_[1e-3, 0.0, 0.0, 0.0, 0.0, 0.0]
    scale = np.r_[1e-3 / np.sqrt(8.0), np.full(5, 1.0)]       # J(0) = -1/2 (1 / (1 / sqrt 8))^2 = -4
    x = move_target(quadratic(mode, scale), 8, np.zeros(6), CLOUD, FLOOR, np.full(6, 1e9),
                      np.random.default_rng(0)).x
    assert x is not None and abs(x[0] - 1e-3) < 0.2e-3


def test_the_width_offset_is_taken_only_when_it_clearly_explains_the_window():
    """width_target: a 7-D quadratic (pose, width offset w px) whose mode has w = 2 px is
    found with w's prior N(0, WIDTH_SIGMA^2), the gain computed by hand; a mode at w = 0.3 px
    gains less than WIDTH_MARGIN over the pose alone: None."""
    scale = np.r_[np.full(6, 1e-3), 0.2]
    flat = np.r_[np.full(6, 1e9)]
    cloud = np.diag(np.full(6, 1e-4) ** 2)
    s2 = window_move.WIDTH_SIGMA ** 2
    for seed in range(3):
        x = window_move.width_target(quadratic(np.r_[np.zeros(6), 2.0], scale), np.zeros(6), 0.0, cloud,
                                     np.full(6, 1e-3), flat, np.random.default_rng(seed), gain=0.0)
        w = 2.0 * (1 / 0.04) / (1 / 0.04 + 1 / s2)                       # the posterior mode in w
        assert x is not None and abs(x[6] - w) < 0.02 and np.abs(x[:6]).max() < 2e-4
    J = quadratic(np.r_[np.zeros(6), 0.3], scale)
    gain_by_hand = -0.5 * (0.3 / 0.2) ** 2 * (1 - 1 / (1 + 0.04 / s2)) + 0.5 * (0.3 / 0.2) ** 2
    assert gain_by_hand < window_move.WIDTH_MARGIN
    assert window_move.width_target(J, np.zeros(6), 0.0, cloud, np.full(6, 1e-3), flat,
                                    np.random.default_rng(0), gain=0.0) is None
    # a clear width mode that the pose alone nearly matches is not taken either
    assert window_move.width_target(quadratic(np.r_[np.zeros(6), 2.0], scale), np.zeros(6), 0.0, cloud,
                                    np.full(6, 1e-3), flat, np.random.default_rng(0), gain=48.0) is None


def _inward(obs, px):
    """The observation with each edge's pixel set moved ``px`` towards the other set (a
    detector that finds both edges inside the limbs)."""
    sets = [np.asarray(p, float) for p in obs.pixels]
    c = [s.mean(axis=0) for s in sets]
    moved = []
    for i, s in enumerate(sets):
        d = s[-1] - s[0]
        n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        n = n if n @ (c[1 - i] - c[i]) > 0 else -n
        moved.append(s + px * n)
    return replace(obs, pixels=moved)


def test_edges_found_inside_the_limbs_on_every_frame_set_the_width_offset():
    """Edges 2 px inside the limbs on every frame: the move takes the joint mode with the
    width offset (about 2 px) and the filter ends nearer the true E than without it; on the
    same frames unmoved, the width stays 0 (test_no_move_without_a_clear_gain's frames)."""
    rng = np.random.default_rng(3)
    frames = [(fr, _inward(obs, 2.0)) for fr, obs in _frames(SCENE.true_E(np.zeros(6)), SCHEDULE[-1], rng)]
    err = {}
    for on in (True, False):
        pf = ParticleFilter(SCENE.ctx, particles=300, seed=0, search=False, init_std_b=1e-3, init_std_w=5e-3,
                            edge_width=on)
        for fr, obs in frames:
            est = pf.step(fr, obs)
        err[on] = np.linalg.norm(est.E[:3, 3] - SCENE.true_E(np.zeros(6))[:3, 3])
        if on:
            assert 1.0 < pf.width < 2.7      # 2 px, shrunk by its prior (1.5 px): 1.5 here
            assert pf.report()["width_offset_px"] == round(pf.width, 3)    # metrics.json's estimator_report
        else:
            assert pf.width == 0.0
    assert err[True] < 0.5 * err[False]
    pf = ParticleFilter(SCENE.ctx, particles=300, seed=0, search=False, init_std_b=1e-3, init_std_w=5e-3)
    for fr, obs in _frames(SCENE.true_E(np.zeros(6)), SCHEDULE[-1], np.random.default_rng(3)):
        pf.step(fr, obs)
    assert pf.width == 0.0
