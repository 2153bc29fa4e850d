"""graphtrack.estimate.reinit: the innovation gate, the lock's covariance gate, the prior
guard, the smoother's restart and refused updates, the window challenge and the
candidate test's motion requirement, on the synthetic world
(tests/robust_world.py).

Oracles: the lock gate against the quadratic form computed by hand; the gate's
effect against the same run with the gate off (an occluder's edges pull an
ungated estimator by millimetres, the gated one stays within the motion model's
reach); the prior guard, the restart and the window challenge against the known true E;
the candidate's motion against the robot's feature model.
"""
from __future__ import annotations

import numpy as np
import pytest

from graphtrack.detect.base import Observation
from graphtrack.estimate.divergence import misfit
from graphtrack.estimate import make_estimator
from graphtrack.estimate.reinit import BLIND_MISFIT, LOCK_FLOOR, PRIOR_GATE, SearchInit, _Candidate
from graphtrack.estimate.startup import SearchResult
from graphtrack.geometry.se3 import bw_to_matrix, invert, matrix_to_bw
from graphtrack.io.frame import Frame
from graphtrack.robot.features import base_features, shaft_lines
from robust_world import make_world

MODEL = "line-intensities"
SPREAD = np.array([6e-3] * 3 + [0.05] * 3)


def _obs(world, q, E, seed):
    """Noisy observations of the shaft and markers seen through E."""
    from graphtrack.sim import synthetic as syn

    return syn.observe(world.scene, q, E, np.random.default_rng(seed), pixel_noise=0.5, outliers=0.02,
                       marker_noise=0.5).observation(MODEL)


def _one_edge(world, q, E, seed):
    """As :func:`_obs`, the first edge's pixel set alone (no markers): the tool re-entering,
    or an occluder's edge."""
    both = _obs(world, q, E, seed)
    return Observation(MODEL, pixels=both.pixels[:1], edge_ids=both.edge_ids[:1])


def _frame(world, t):
    q = world.joints(t)
    return q, Frame(t, t / 30.0, None, q[:6], q[6])


def test_near_lock_is_the_covariance_gate_computed_by_hand():
    world = make_world(0, 3.0, 1.5)
    Q = np.diag(np.square([2.5e-5] * 3 + [1e-4] * 3))
    policy = SearchInit(world.ctx, motion_cov=Q)
    cov = np.diag(np.square([1e-3, 1e-3, 2e-3, 0.004, 0.004, 0.01]))
    policy.unused = 7
    C = cov + 7 * Q + np.diag((LOCK_FLOOR * SPREAD) ** 2)
    x_cur = np.zeros(6)
    for axis in range(6):
        step = np.zeros(6)
        step[axis] = np.sqrt(C[axis, axis] * PRIOR_GATE)      # exactly on the gate along one axis
        assert policy.near_lock(0.99 * step, x_cur, cov)
        assert not policy.near_lock(1.01 * step, x_cur, cov)
    assert policy.near_lock(np.full(6, 1.0), x_cur, None)      # no covariance: no gate


def _lock(world, est_name="smoother", frames=15, **kw):
    est = make_estimator(est_name, world.ctx, **kw)
    for t in range(frames):
        q, fr = _frame(world, t)
        est.step(fr, _obs(world, q, world.E_true, t))
    return est


@pytest.mark.parametrize("name", ["smoother", "pf"])
def test_an_occluder_frame_on_a_good_lock_is_predicted_through(name):
    """Frames whose edges and markers belong to a pose 8 mm off (an instrument lying over
    the shaft) are outlier frames: the gated estimator keeps its lock, the ungated one
    is pulled towards the occluder."""
    world = make_world(3, 3.0, 1.5)
    occluder = bw_to_matrix(np.array([0.008, 0.0, 0.0, 0.0, 0.0, 0.0])) @ world.E_true
    kw = {"particles": 500, "seed": 1} if name == "pf" else {}
    moved = {}
    for gate in (True, False):
        est = _lock(world, name, **kw)
        policy = est.search if name == "pf" else est.reinit
        policy.innovation_gate = gate
        assert policy.locked
        lock = est.E if name == "pf" else est.last.matrix()
        poses, flags = [], []
        for t in range(15, 35):
            q, fr = _frame(world, t)
            e = est.step(fr, _obs(world, q, occluder, t))
            poses.append(e.E)
            flags.append(e.extra["outlier"])
        moved[gate] = np.linalg.norm(matrix_to_bw(poses[-1] @ invert(lock))[:3])
        # the smoother's estimates outside the prior's region, and its refused updates
        contained = getattr(est, "contained", 0) + getattr(est, "refused", 0)
        if gate:
            assert policy.rejections >= 15 and sum(flags) == policy.rejections + contained   # trajectory.csv's
            # metrics.json's estimator_report counts the same outlier frames as the column
            assert est.report()["outlier_frames"] + contained == sum(flags)
        else:
            assert policy.rejections == 0 and sum(flags) == contained
    assert moved[True] < 1.5e-3, moved
    assert moved[False] > 2 * moved[True], moved


class _Overshoot:
    """A gtsam fixed-lag smoother whose newest estimate is moved by ``offset`` (left (b, w))
    while ``armed``: what an undamped Gauss-Newton step that overshoots returns."""

    def __init__(self, inner, offset):
        self.inner, self.offset, self.armed = inner, np.asarray(offset, float), False

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def calculateEstimatePose3(self, key):
        import gtsam

        pose = self.inner.calculateEstimatePose3(key)
        return gtsam.Pose3(bw_to_matrix(self.offset) @ pose.matrix()) if self.armed else pose


@pytest.mark.parametrize("refuse", [True, False])
def test_a_smoother_update_that_explains_its_frame_worse_is_refused(refuse):
    """An update 3 mm off the pose before it (an overshooting step, injected) explains its
    clean frame far worse than the pose before did. It is not reported: the pose before
    it is (covariance + one motion step Q), flagged an outlier; the window restarts there
    (covariance + 2 Q on the next frame, checked on one without detections), and the next
    frames track the truth again. With the refusal off the overshoot is reported."""
    world = make_world(3, 3.0, 1.5)
    est = _lock(world, **({} if refuse else {"refuse_misfit_rise": None}))
    assert est.refused == 0                  # no refusal on 15 clean frames
    est.smoother = _Overshoot(est.smoother, [0.003, 0.0, 0.0, 0.0, 0.0, 0.0])
    est.smoother.armed = True
    before, before_cov = est.last.matrix(), est.last_cov.copy()
    q, fr = _frame(world, 15)
    e = est.step(fr, _obs(world, q, world.E_true, 15))
    moved = np.linalg.norm(matrix_to_bw(e.E @ invert(before))[:3])
    if not refuse:
        assert moved > 2.5e-3 and e.extra["outlier"] == 0.0
        return
    assert est.refused == 1 and e.extra["outlier"] == 1.0
    np.testing.assert_allclose(e.E, before, atol=1e-12)
    np.testing.assert_allclose(e.std, np.sqrt(np.diag(before_cov + est.motion_cov)), rtol=1e-9)
    # the window restarts at that pose: a frame without detections has its prior alone,
    # the pose before and its covariance + two motion steps (through gtsam's right frame)
    q, fr = _frame(world, 16)
    e = est.step(fr, Observation(MODEL))
    assert est.started and est.refused == 1
    np.testing.assert_allclose(e.E, before, atol=1e-9)
    np.testing.assert_allclose(e.std, np.sqrt(np.diag(before_cov + 2 * est.motion_cov)), rtol=1e-6)
    errors = []
    for t in range(17, 27):
        q, fr = _frame(world, t)
        e = est.step(fr, _obs(world, q, world.E_true, t))
        errors.append(np.linalg.norm(matrix_to_bw(e.E @ invert(world.E_true))[:3]))
    assert max(errors) < 1e-3, errors


def test_a_lock_uses_only_frames_it_explains_as_well_as_those_that_formed_it():
    """While locked, a frame whose misfit at the estimate lies between the lock's threshold
    and the monitor's (a partial occluder: edges near the prediction) is an outlier
    frame; the same frame before a lock is used and neither extends nor ends the run."""
    world = make_world(3, 3.0, 1.5)
    policy = SearchInit(world.ctx, seed=0)
    q, _ = _frame(world, 0)
    policy.propose(q, _obs(world, q, world.E_true, 0), world.ctx.handeye, True)
    x_true = matrix_to_bw(world.E_true @ invert(world.ctx.handeye))
    q, _ = _frame(world, 1)
    partial = None
    for turn in np.linspace(0.005, 0.06, 23):        # about the optical axis, rad: the misfit rises smoothly
        obs = _obs(world, q, bw_to_matrix(np.array([0, 0, 0, 0, 0, turn])) @ world.E_true, 1)
        m = misfit(*policy.scorer.with_floor(q, obs, x_true))
        if policy.lock_threshold < m <= policy.threshold:
            partial = obs
            break
    assert partial is not None
    policy.propose(q, partial, world.E_true, True)
    assert not policy.rejected and policy.lock_run == 0            # unlocked: used, the run unchanged
    for t in range(2, 2 + policy.lock_frames):
        qt, _ = _frame(world, t)
        policy.propose(qt, _obs(world, qt, world.E_true, t), world.E_true, True)
    assert policy.locked and not policy.rejected
    policy.propose(q, partial, world.E_true, True)
    assert policy.rejected and policy.rejections == 1


def test_a_lock_from_before_a_gap_is_earned_again():
    """After ``gap`` frames without detections the lock is stale (E drifts with the arm's
    configuration while the tool is unseen): the first frames back are used, not gated,
    even when the prediction explains them only partly (misfit between the lock's
    threshold and the monitor's); the same frame on a lock without a gap is an outlier."""
    world = make_world(3, 3.0, 1.5)
    x_true = matrix_to_bw(world.E_true @ invert(world.ctx.handeye))
    q_back, _ = _frame(world, 40)
    partial = None
    for turn in np.linspace(0.005, 0.06, 23):        # about the optical axis, rad: the misfit rises smoothly
        obs = _obs(world, q_back, bw_to_matrix(np.array([0, 0, 0, 0, 0, turn])) @ world.E_true, 40)
        m = misfit(*SearchInit(world.ctx, seed=0).scorer.with_floor(q_back, obs, x_true))
        if 0.25 < m <= 0.5:
            partial = obs
            break
    assert partial is not None
    for gap in (0, 30):
        policy = SearchInit(world.ctx, seed=0, gap=30)
        for t in range(1 + policy.lock_frames):
            qt, _ = _frame(world, t)
            policy.propose(qt, _obs(world, qt, world.E_true, t), world.E_true, True)
        assert policy.locked
        for t in range(gap):
            qt, _ = _frame(world, 12 + t)
            policy.propose(qt, Observation(MODEL), world.E_true, False)
        policy.propose(q_back, partial, world.E_true, True)
        assert policy.rejected == (gap == 0), gap
        assert policy.locked == (gap == 0)


def test_the_smoother_never_reports_an_estimate_outside_the_prior_region():
    """Ungated, an occluder 8 mm off drags the smoother's Gauss-Newton steps past the hand-eye
    prior's region (prior_distance computed by hand below). Such an estimate is not reported:
    on that frame the pose before it is (its std finite), the frame is flagged an outlier,
    and the next frames start up afresh."""
    world = make_world(3, 3.0, 1.5)
    occluder = bw_to_matrix(np.array([0.008, 0.0, 0.0, 0.0, 0.0, 0.0])) @ world.E_true
    est = _lock(world)
    est.reinit.innovation_gate = False
    previous = est.last.matrix()
    seen = []
    for t in range(15, 35):
        q, fr = _frame(world, t)
        e = est.step(fr, _obs(world, q, occluder, t))
        x = matrix_to_bw(e.E @ invert(world.ctx.handeye))
        assert np.sum((x / SPREAD) ** 2) <= PRIOR_GATE
        assert np.all(np.isfinite(e.std))
        if est.contained > len(seen):
            seen.append(t)
            np.testing.assert_allclose(e.E, previous, atol=1e-12)
            assert e.extra["outlier"] == 1.0
        previous = e.E
    assert seen, "the occluder never dragged the estimate out: the test does not test"


def test_prior_guard_re_initialises_a_run_away_estimate_near_the_truth():
    world = make_world(5, 4.0, 2.0)
    policy = SearchInit(world.ctx, seed=0)
    q0, _ = _frame(world, 0)
    assert policy.propose(q0, _obs(world, q0, world.E_true, 0), world.ctx.handeye, True) is not None
    run_away = bw_to_matrix(np.array([0.04, -0.03, 0.0, 0.2, 0.0, 0.0])) @ world.E_true
    q1, _ = _frame(world, 1)
    E = policy.propose(q1, _obs(world, q1, world.E_true, 1), run_away, True)
    assert policy.guarded == 1 and E is not None
    assert not policy.outside(matrix_to_bw(E @ invert(world.ctx.handeye)))
    # one frame: the search is good to a few mm (least along the shaft), the run-away was 50 mm off
    assert np.linalg.norm(matrix_to_bw(E @ invert(world.E_true))[:3]) < 6e-3


def test_smoother_restarts_after_a_gap_and_reacquires_a_moved_tool():
    """The tool unseen for 40 frames while E moves 6 mm across the shaft (a re-draped arm;
    along it, 6 mm is the markers' spacing and maps one marker onto the next): after the gap
    the search re-initialises and the smoother restarts its window. Oracle: its own
    accuracy after a start-up of the same length (a fresh start at the moved pose sees
    the same information): within 15 frames it is within 2 mm of it, and it keeps
    converging; no pose or std is NaN."""
    world = make_world(8, 3.0, 1.5)
    est = _lock(world, frames=20)
    fresh = np.linalg.norm(matrix_to_bw(est.last.matrix() @ invert(world.E_true))[:3])
    moved = bw_to_matrix(np.array([0.006, 0.0, 0.0, 0.0, 0.0, 0.0])) @ world.E_true   # across the shaft
    errs = []
    for t in range(20, 110):
        q, fr = _frame(world, t)
        obs = Observation(MODEL) if t < 60 else _obs(world, q, moved, t)
        e = est.step(fr, obs)
        assert np.all(np.isfinite(e.E)) and np.all(np.isfinite(e.std))
        errs.append(np.linalg.norm(matrix_to_bw(e.E @ invert(moved))[:3]))
    assert est.restarts >= 1
    assert errs[59 - 20] > 5e-3                     # the prediction through the gap: the tool moved
    after = np.array(errs[60 - 20:])
    assert np.all(after[15:] < fresh + 2e-3), (fresh, after)
    assert after[-1] < after[15]


def test_after_a_gap_one_edge_makes_a_candidate_not_an_adoption():
    """The tool re-enters the view an edge at a time: one edge of a pose 3 mm off, after
    40 frames unseen, does not explain the prediction, and a search mode fit to it is set
    along what the edge does not see by the hand-eye prior alone. The frame starts a
    candidate (the multi-frame test decides) and the window challenge's schedule restarts;
    nothing is adopted on that one frame, and the estimator predicts through it (an
    outlier frame, not in the challenge's history)."""
    world = make_world(8, 3.0, 1.5)
    policy = SearchInit(world.ctx, seed=0, window=6)
    q, _ = _frame(world, 0)
    assert policy.propose(q, _obs(world, q, world.E_true, 0), world.ctx.handeye, True) is not None
    for t in range(1, 12):
        q, _ = _frame(world, t)
        assert policy.propose(q, _obs(world, q, world.E_true, t), world.E_true, True) is None
    for t in range(12, 52):
        q, _ = _frame(world, t)
        assert policy.propose(q, Observation(MODEL), world.E_true, False) is None
    moved = bw_to_matrix(np.array([0.003, -0.002, 0.0, 0.0, 0.0, 0.0])) @ world.E_true
    q, _ = _frame(world, 52)
    one = _one_edge(world, q, moved, 52)
    count = policy.count
    assert policy.propose(q, one, world.E_true, True) is None
    assert policy.count == count and policy.candidate is not None
    assert policy.rejected and policy.used == 0     # the challenge counts frames from the gap


def test_after_a_gap_the_estimate_is_held_through_frames_it_does_not_explain():
    """After 40 frames unseen, an occluder's edge 3 mm off (nothing of the tool in view) is
    not taken as the tool's: the smoother predicts through the first ``confirm`` frames the
    prediction does not explain (its pose does not move; used, that one edge moved it
    12 mm). Once a frame is explained again (the tool back where it was) the re-entry ends
    and the frames are used; of frames not explained, every (confirm + 1)-th is used, so a
    tool that really moved while unseen is re-acquired
    (test_smoother_restarts_after_a_gap_and_reacquires_a_moved_tool)."""
    world = make_world(8, 3.0, 1.5)
    est = _lock(world, frames=20)
    for t in range(20, 60):
        q, fr = _frame(world, t)
        est.step(fr, Observation(MODEL))
    held = est.last.matrix()
    occluder = bw_to_matrix(np.array([0.003, 0.0, 0.0, 0.0, 0.0, 0.0])) @ world.E_true
    q, fr = _frame(world, 60)
    e = est.step(fr, _one_edge(world, q, occluder, 60))
    assert est.reinit.rejected and est.reinit.reentry
    np.testing.assert_allclose(e.E, held, atol=1e-9)
    q, fr = _frame(world, 61)
    est.step(fr, _obs(world, q, world.E_true, 61))
    assert not est.reinit.rejected and not est.reinit.reentry


def test_after_a_gap_every_sixth_unexplained_frame_is_used():
    """While no frame after a gap is explained, a frame is an outlier frame unless the
    ``confirm`` (5) before it were: the policy, its estimate held at the truth, sees an
    occluder's edge 3 mm off on every frame: 5 outlier frames, 1 used, 5 more."""
    world = make_world(8, 3.0, 1.5)
    policy = SearchInit(world.ctx, seed=0, monitor=False)
    for t in range(12):
        q, _ = _frame(world, t)
        policy.propose(q, _obs(world, q, world.E_true, t), world.E_true, True)
    for t in range(12, 52):
        q, _ = _frame(world, t)
        policy.propose(q, Observation(MODEL), world.E_true, False)
    occluder = bw_to_matrix(np.array([0.003, 0.0, 0.0, 0.0, 0.0, 0.0])) @ world.E_true
    flags = []
    for t in range(52, 64):
        q, _ = _frame(world, t)
        policy.propose(q, _one_edge(world, q, occluder, t), world.E_true, True)
        flags.append(policy.rejected)
    assert flags == [True] * 5 + [False] + [True] * 5 + [False]


def _history(world, policy, x_est, frames=16):
    """Fill the policy's history with frames seen through the true E, each estimated at x_est."""
    for t in range(frames):
        q, _ = _frame(world, 3 * t)
        obs = _obs(world, q, world.E_true, 100 + t)
        policy.history.append((q, obs, float(policy.scorer(q, obs, x_est[None])[0])))


def test_window_challenge_replaces_a_wrong_mode_and_keeps_a_right_one():
    """An estimate 5 mm along the shaft and 2 deg off (a mode one frame barely tells from the
    truth) is replaced by the several-frame search's mode, which lies near the known true E;
    an estimate at the truth is kept (no gain beyond the threshold)."""
    world = make_world(7, 4.0, 2.0)
    x_true = matrix_to_bw(world.E_true @ invert(world.ctx.handeye))
    x_wrong = x_true + np.array([0.004, -0.003, 0.0, 0.0, 0.035, 0.0])
    policy = SearchInit(world.ctx, seed=0, window=6)
    _history(world, policy, x_wrong)
    E = policy._challenge(x_wrong, None)
    assert E is not None and policy.switches == 1 and len(policy.history) == 0
    q, _ = _frame(world, 45)
    tip = lambda E: base_features(world.ctx.robot, q).transformed(E).tip   # noqa: E731
    wrong = np.linalg.norm(tip(bw_to_matrix(x_wrong) @ world.ctx.handeye) - tip(world.E_true))
    assert wrong > 8e-3 and np.linalg.norm(tip(E) - tip(world.E_true)) < 2.5e-3
    policy = SearchInit(world.ctx, seed=0, window=6)
    _history(world, policy, x_true)
    assert policy._challenge(x_true, None) is None and policy.switches == 0 and policy.challenges == 1


def test_window_challenge_runs_once_after_8_frames_used():
    world = make_world(7, 4.0, 2.0)
    est = make_estimator("smoother", world.ctx)
    for t in range(40):
        q, fr = _frame(world, t)
        est.step(fr, _obs(world, q, world.E_true, t))
    assert est.reinit.challenges == 1
    assert make_estimator("pf", world.ctx, particles=200).search.window == 0


def test_a_switch_by_the_challenge_does_not_restart_its_schedule():
    """An estimator that stays at a wrong mode (5 mm along the shaft, 2 deg) makes the
    challenge switch at 8 frames used; no second challenge follows (a restarted count
    would challenge, and switch, every 8 frames)."""
    world = make_world(7, 4.0, 2.0)
    x_true = matrix_to_bw(world.E_true @ invert(world.ctx.handeye))
    wrong = bw_to_matrix(x_true + np.array([0.004, -0.003, 0.0, 0.0, 0.035, 0.0])) @ world.ctx.handeye
    policy = SearchInit(world.ctx, seed=0, window=6, monitor=False, innovation_gate=False)
    q, _ = _frame(world, 0)
    assert policy.propose(q, _obs(world, q, world.E_true, 0), world.ctx.handeye, True) is not None
    adopted_at, after = [], []
    for t in range(1, 41):
        q, _ = _frame(world, 3 * t)
        if policy.propose(q, _obs(world, q, world.E_true, t), wrong, True) is not None:
            adopted_at.append(t)
            after.append((policy.used, len(policy.history)))
    assert adopted_at == [8] and policy.switches == 1 and policy.challenges == 1
    assert after == [(8, 0)]      # the count kept, the history restarted at the switch


def _lines_by_features(world, q, x):
    """(2, 2) shaft lines (rho px, theta rad) of E = Exp(x) . E_0 at reading q, through the
    robot's feature model (not the particle filter's batched projection the policy uses)."""
    E = bw_to_matrix(x) @ world.ctx.handeye
    rho, theta, valid = shaft_lines(base_features(world.ctx.robot, q).transformed(E), world.ctx.camera.K)
    assert bool(valid)
    return np.stack([rho, theta], -1)


def _confirmation(world, times, x_cand, x_cur):
    """Run a candidate's sequential test over the frames ``times`` (observations of the
    true E); returns the frame count at which it adopted (None: never) and the policy."""
    policy = SearchInit(world.ctx, seed=0)
    policy.candidate = _Candidate(SearchResult(x_cand, np.diag(SPREAD ** 2) * 1e-4, 0.0, 0.0))
    for n, t in enumerate(times, start=1):
        q = world.joints(t)
        obs = _obs(world, q, world.E_true, t)
        ll_cur, floor = policy.scorer.with_floor(q, obs, x_cur)
        if policy._test(q, obs, ll_cur, misfit(ll_cur, floor), x_cur) is not None:
            return n, policy
        if policy.candidate is None:
            return None, policy
    return None, policy


def test_a_candidate_is_confirmed_only_once_the_tool_has_moved():
    """The candidate test decides on frames where the tool moved: with the readings frozen
    (a static occluder's edges would keep fitting a wrong candidate) it runs on to ``gap``
    frames; with the tool moving it decides after ``confirm``. The motion it measures is
    max |d rho| + |d theta| * half-diagonal of the candidate's lines, checked against the
    robot's feature model."""
    world = make_world(7, 3.0, 1.5)
    x_true = world.x_true
    x_cur = x_true + np.array([0.008, 0.0, 0.0, 0.0, 0.0, 0.0])     # a lost lock 8 mm off
    policy = SearchInit(world.ctx)
    assert policy.min_motion == pytest.approx(12.0)                 # 2 x the 3-sigma floor at 2 px
    static = [0] * 40
    n, policy = _confirmation(world, static, x_true, x_cur)
    assert n == policy.gap and policy.candidate is None and policy.count == 1
    moving = [0, 15, 30, 45, 60, 75]
    a, b = _lines_by_features(world, world.joints(0), x_true), None
    motion = [0.0]
    for t in moving[1:]:
        b = _lines_by_features(world, world.joints(t), x_true)
        d = np.abs(b - a)
        motion.append(max(motion[-1], float(np.max(d[:, 0] + d[:, 1] * policy.half_diagonal))))
    first = next(i for i, m in enumerate(motion, start=1) if m >= policy.min_motion)
    assert first <= policy.confirm          # the trajectory moves enough within confirm frames
    n, policy = _confirmation(world, moving, x_true, x_cur)
    assert n == policy.confirm
    # adopted: the search re-run on that one frame, good to a few mm (the lock was 8 mm off)
    assert np.linalg.norm(policy.result.x[:3] - x_true[:3]) < 6e-3


def test_a_candidate_the_locks_own_frames_contradict_is_vetoed():
    """The lock's evidence (the latest frames it explained): a candidate 8 mm off loses them
    by far more than the margin and is vetoed; the true E against that 8 mm lock is not;
    without evidence (a fresh policy) nothing is vetoed; a gap and an adoption forget it."""
    world = make_world(3, 3.0, 1.5)
    x_true = matrix_to_bw(world.E_true @ invert(world.ctx.handeye))
    policy = SearchInit(world.ctx, seed=0, gap=30)
    far = x_true + np.r_[0.008, 0, 0, 0, 0, 0]
    assert not policy._contradicts_evidence(far, x_true)                # no evidence yet
    for t in range(1 + policy.lock_frames):
        qt, _ = _frame(world, t)
        policy.propose(qt, _obs(world, qt, world.E_true, t), world.E_true, True)
    assert policy.locked and len(policy.evidence) > 0
    # the oracle: the frames' own likelihoods, summed by hand
    ll = sum(policy.scorer(q, o, np.stack([far, x_true])) for q, o in policy.evidence)
    assert ll[0] - ll[1] < -len(policy.evidence) * policy.margin
    assert policy._contradicts_evidence(far, x_true)
    assert not policy._contradicts_evidence(x_true, far)          # the evidence favours it: no veto
    assert not policy._contradicts_evidence(x_true, x_true)
    for t in range(30):                                                  # a gap: the lock is stale
        qt, _ = _frame(world, 20 + t)
        policy.propose(qt, Observation(MODEL), world.E_true, False)
    qt, _ = _frame(world, 50)
    policy.propose(qt, _obs(world, qt, world.E_true, 50), world.E_true, True)
    assert len(policy.evidence) <= 1 and all(q is qt for q, _ in policy.evidence)   # none from before
    policy._adopt(SearchResult(x_true, np.eye(6) * 1e-6, 0.0, 0.0))
    assert len(policy.evidence) == 0


def test_frames_that_show_nothing_of_the_tool_age_the_evidence_as_a_gap_does():
    """Detections the lock explains none of (misfit >= BLIND_MISFIT at the estimate, computed
    here by the scorer itself: edges and markers of a pose 40 mm off, as a detector's false
    edges while the tool is out of view) for ``gap`` frames in a row drop the lock's
    evidence, as ``gap`` frames without detections do; one frame fewer keeps it, and a frame
    the lock explains in between starts the count again."""
    world = make_world(3, 3.0, 1.5)
    elsewhere = bw_to_matrix(np.array([0.04, 0.0, 0.0, 0.0, 0.0, 0.0])) @ world.E_true

    def locked_policy():
        policy = SearchInit(world.ctx, seed=0, gap=10)
        for t in range(1 + policy.lock_frames):
            qt, _ = _frame(world, t)
            policy.propose(qt, _obs(world, qt, world.E_true, t), world.E_true, True)
        assert policy.locked and len(policy.evidence) > 0
        return policy

    def blind(policy, t):
        qt, _ = _frame(world, t)
        obs = _obs(world, qt, elsewhere, t)
        assert policy.misfit_at(qt, obs, world.E_true) >= BLIND_MISFIT     # the oracle: nothing explained
        policy.propose(qt, obs, world.E_true, True)

    policy = locked_policy()
    for t in range(policy.gap - 1):
        blind(policy, 20 + t)
    assert len(policy.evidence) > 0
    blind(policy, 20 + policy.gap)
    assert len(policy.evidence) == 0

    policy = locked_policy()
    for t in range(policy.gap - 1):
        blind(policy, 20 + t)
    qt, _ = _frame(world, 40)
    policy.propose(qt, _obs(world, qt, world.E_true, 40), world.E_true, True)   # explained again
    n = len(policy.evidence)
    for t in range(policy.gap - 1):
        blind(policy, 50 + t)
    assert len(policy.evidence) == n > 0
