"""Online fixed-lag factor-graph estimator of the lumped error E_t.

One gtsam.Pose3 E_t per frame (key x_t; y_t once settled). Factors:

- frame 0: PriorFactorPose3(E_0 = ctx.handeye), left (b, w) stds (prior_sigma_b m,
  prior_sigma_w rad);
- every frame t > 0, always (so gaps and degenerate views stay solvable):
  BetweenFactorPose3(x_{t-1}, x_t, identity), left stds (motion_sigma_b m,
  motion_sigma_w rad) per frame, the particle filter's random walk;
- the frame's robust detection factors (:func:`graphtrack.estimate.graph.frame_factors`;
  in stereo also the right image's, :mod:`graphtrack.estimate.stereo`);
- edge-bias vector b_j per frames jn .. jn + n - 1 (n = ``edge_bias_every``), its
  prior and Gauss-Markov chain (:mod:`factors.edge_bias`); shaft pixels on (x_t, b_j),
  polar lines on it only once settled. A block's variables share its first frame's
  timestamp, so the window holds ``lag`` to ``lag`` + (n - 1) frames.

Start-up: the first frame with detections is solved alone by Levenberg-Marquardt
(shaft factors, then with markers; markers-only frames held back up to
``start_up_wait``), or from the global search's mode (:mod:`graphtrack.estimate.reinit`) in
one stage with all the frame's factors. A re-initialisation by that policy restarts the
window (the frame is started up as the first one); an outlier frame of its innovation
gate adds only the motion factor.
Containment: an estimate outside the hand-eye prior's region (the policy's prior
gate; the lumped error never leaves it) is not reported: the window is dropped, the
pose before the frame is reported (covariance + one motion step; the prior's if that
pose was outside too), the frame counts as an outlier frame, and the policy starts
up afresh (docs/decisions/contained-estimate.md). Refusal: nor is an update whose
pose explains its frame worse than the pose before it (the policy's misfit of the
left image, :func:`graphtrack.estimate.divergence.misfit`, higher by more than
``refuse_misfit_rise``; None: off; not judged without a covariance or on a degenerate
misfit): robust factors kept edges that are not the shaft's, or a Gauss-Newton step
overshot. The pose before is reported, the frame is an outlier frame, and the window
restarts with a prior at that pose and covariance (docs/decisions/refused-update.md).
Both need the policy (``search``). Its window challenge (``search_window`` frames; 0: off)
re-searches on several frames 8 frames after each start (window-challenge.md).
iSAM2 (default) or BatchFixedLagSmoother keeps the last ``lag`` s. Estimate of frame
t: x_t right after frame t's update (filtered); cov/std: its marginal in the left
(b, w) perturbation. iSAM2 relinearises at ``relinearize_threshold`` (rad / m of
gtsam's right perturbation) and, from ``settle`` s after start-up, settled keys y_t
at ``settled_relinearize_threshold``.

Decisions and measurements: docs/decisions/bias-block-timestamps.md,
smoother-start-up.md, settled-relinearisation.md, startup-search.md, window-challenge.md.
"""
from __future__ import annotations

import dataclasses
import time

import gtsam
import numpy as np

from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.estimate.base import STD_COLUMNS, Estimate, monotone_stamp
from graphtrack.estimate.options import (LAG_S, MOTION_SIGMA_B, MOTION_SIGMA_W, PRIOR_SIGMA_B, PRIOR_SIGMA_W,
                                         SEARCH, SEARCH_STD_B, SEARCH_STD_W, SMOOTHER)
from graphtrack.io.frame import Frame
from graphtrack.io.context import TrackingContext
from graphtrack.estimate.gating import smoother_gate
from graphtrack.estimate.reinit import SearchInit
from graphtrack.robot.features import base_features
from graphtrack.estimate.graph import (edge_bias_factors, estimate_extra, gaussian_bw,
                                       key, left_from_right_cov, right_from_left_cov, split_options)
from graphtrack.estimate.stereo import stereo_factor_groups
from factors.edge_bias import BIAS_DIM, bias_key, bias_prior_factor, transition

#: misfit rise (a fraction of the frame's evidence, 0..1) beyond which an update is refused
REFUSE_MISFIT_RISE = 0.2


class FixedLagSmootherEstimator:
    """Fixed-lag smoother over E_t (see the module docstring).

    Options: lag (s), smoother ("isam2" | "batch"), markers, prior_sigma_b/_w,
    start_up (the LM initialisation of the first frame with detections),
    start_up_iterations, start_up_wait (frames of markers-only detections held
    back before starting without the shaft; none for a tool without shaft features),
    motion_sigma_b/_w (per frame), iterations (extra iSAM2 passes per frame
    while the newest state still moves more than ``converge_tol``),
    relinearize_threshold, settled_relinearize_threshold and settle (s; see
    the module doc), fps (stamps fallback), covariance (compute the marginal each
    frame), refuse_misfit_rise (module doc), marker_gate_follows_covariance (the marker
    gate is 3.72 sigma of the predicted markers, at most marker_gate: gating.smoother_gate),
    plus :class:`graphtrack.estimate.graph.FactorOptions` (pixel_sigma, line_sigma_rho,
    line_sigma_theta, marker_sigma, marker_gate, robust, robust_k, max_pixels).
    """

    name = "smoother"
    uses_observations = True
    offline = False
    stochastic = False
    supported_observations = OBSERVATION_MODELS
    extra_columns = STD_COLUMNS + ("smoother_ms", "outlier")

    def __init__(self, ctx: TrackingContext, lag: float = LAG_S,
                 smoother: str = SMOOTHER, markers: bool = True,
                 prior_sigma_b: float = PRIOR_SIGMA_B, prior_sigma_w: float = PRIOR_SIGMA_W,
                 motion_sigma_b: float = MOTION_SIGMA_B, motion_sigma_w: float = MOTION_SIGMA_W,
                 iterations: int = 1, converge_tol: float = 1e-4,
                 relinearize_threshold: float = 1e-2, settled_relinearize_threshold: float = 2e-2,
                 settle: float = 2.0, fps: float = 30.0,
                 covariance: bool = True, start_up: bool = True, start_up_iterations: int = 50,
                 start_up_wait: int = 30, search: bool = SEARCH, search_std_b: float = SEARCH_STD_B,
                 search_std_w: float = SEARCH_STD_W, reinit_gap: int = 30, search_window: int = 6,
                 marker_gate_follows_covariance: bool = True,
                 refuse_misfit_rise: float | None = REFUSE_MISFIT_RISE, **options):
        self.gtsam = gtsam
        self.ctx = ctx
        self.lag = float(lag)
        self.kind = str(smoother).lower()
        if self.kind not in ("isam2", "batch"):
            raise ValueError(f"smoother {smoother!r}: choose isam2 or batch")
        self.fopts, rest = split_options(dict(options, markers=markers))
        rest.pop("name", None)
        self.E0 = np.asarray(ctx.handeye, float)
        self.K = np.asarray(ctx.camera.K, float)
        self.prior_noise = gaussian_bw(self.E0, prior_sigma_b, prior_sigma_w)
        self.motion_noise = gaussian_bw(self.E0, motion_sigma_b, motion_sigma_w)
        self.iterations = int(iterations)
        self.converge_tol = float(converge_tol)
        self.fps = float(fps)
        self.covariance = bool(covariance)
        self.bias = bool(self.fopts.edge_bias)   # pixel sets and polar lines alike
        self.bias_stamp = None        # stamp of the frame that opened the newest bias vector
        self._smoother_params = (float(relinearize_threshold), float(settled_relinearize_threshold))
        self.smoother = self._new_smoother()
        self.k = -1
        self.settle = float(settle)
        self.start_stamp = None       # stamp of the start-up frame
        self.settled = False          # frames from here on are keyed 'y' (see the module doc)
        self.prev_key = None
        self.started = not start_up
        self.start_up_iterations = int(start_up_iterations)
        self.start_up_wait = int(start_up_wait) if ctx.robot.shaft_features else 0
        self.waited = 0
        self.last = gtsam.Pose3(self.E0)
        self.t0 = None
        self.last_stamp = None
        self.timings_ms: list[float] = []
        self.reinit = None
        self.last_cov = None          # marginal covariance of the last x_t (the marker gate)
        self.gate_follows = bool(marker_gate_follows_covariance)   # _gated_options
        self.motion_cov = np.diag(np.square([motion_sigma_b] * 3 + [motion_sigma_w] * 3))
        if search and ctx.robot.shaft_features:   # the search scores shaft edges: none without a shaft
            self.reinit = SearchInit(ctx, (search_std_b, search_std_w), reinit_gap, self.fopts.gate_scale,
                                     markers, motion_cov=self.motion_cov, window=search_window)
            self.start_up_wait = 0    # the search associates markers per hypothesis
        self.restarts = 0             # windows dropped (re-initialisation, containment, refusal)
        self.prior_cov = np.diag(np.square([prior_sigma_b] * 3 + [prior_sigma_w] * 3))
        self.refuse_rise = None if refuse_misfit_rise is None else float(refuse_misfit_rise)
        self.contained = self.refused = 0   # estimates outside the prior's region not reported; updates refused
        self.window_prior = None      # after a refusal: the restarted window's prior noise at self.last

    # -- helpers ---------------------------------------------------------------------
    def _new_smoother(self):
        """An empty gtsam fixed-lag smoother of the configured kind (module doc)."""
        gtsam = self.gtsam
        if self.kind == "batch":
            return gtsam.BatchFixedLagSmoother(self.lag, gtsam.LevenbergMarquardtParams())
        relinearize, settled = self._smoother_params
        p = gtsam.ISAM2Params()
        p.relinearizeSkip = 1
        th = gtsam.ISAM2ThresholdMap()       # per key letter: x (start-up), y (settled), b
        th.insert(("x", np.full(6, relinearize)))
        th.insert(("y", np.full(6, settled)))
        if self.bias:
            # b enters the pixel residuals linearly (only the robust weights depend on
            # it, and they stay at b's linearisation point) and the polar lines' nearly
            # (~0.3 px of rho at a 1-sigma slope, factors/line_parameter.py): relinearising
            # for its moves (px) re-evaluated every pixel factor of the window each
            # frame (10x slower)
            th.insert(("b", np.full(BIAS_DIM, 1e3)))
        p.setRelinearizeThreshold(th)
        return gtsam.IncrementalFixedLagSmoother(self.lag, p)

    def _restart(self) -> None:
        """Drop the window: the next frame opens a new one (a re-initialisation: started up
        as the first frame; a refusal: at its window prior)."""
        self.smoother = self._new_smoother()
        self.prev_key = self.bias_stamp = self.start_stamp = self.last_cov = None
        self.settled = self.started = False
        self.window_prior = None
        self.restarts += 1

    def _contain(self, before, before_cov):
        """(pose, cov) reported instead of an estimate outside the prior's region: the pose
        before this frame, cov + one motion step (the prior's centre and covariance if
        that pose was outside too); the window is dropped and the policy starts over."""
        self.reinit.start_over()
        self.contained += 1
        if self.reinit.outside_pose(before.matrix()):
            before, before_cov = self.gtsam.Pose3(self.E0), None
        return self._fall_back(before, before_cov)

    def _refuse(self, before, before_cov):
        """(pose, cov) reported instead of a refused update (module doc): the pose before
        this frame, cov + Q; the next frame's window prior: that pose, cov + 2 Q."""
        self.refused += 1
        pose, cov = self._fall_back(before, before_cov)
        C = right_from_left_cov(pose.matrix(), cov + self.motion_cov)
        self.window_prior = self.gtsam.noiseModel.Gaussian.Covariance(C)
        self.started = True           # the window opens at its prior, not by a start-up LM
        return pose, cov

    def _fall_back(self, before, before_cov):
        """(before, cov + one motion step; the prior's without one) for this frame; window dropped."""
        self._restart()
        self.last = before
        return before, self.prior_cov if before_cov is None else before_cov + self.motion_cov

    def _worse_than_before(self, frame: Frame, observation, pose) -> bool:
        """The policy's misfit (its floored likelihood) of this frame at ``pose`` exceeds the
        misfit at the pose before, which the policy scored (``reinit.misfit``), by more than
        ``refuse_rise`` (module doc; nan: degenerate, not refused)."""
        m_new = self.reinit.misfit_at(frame.q, observation, pose.matrix())
        return bool(m_new > self.reinit.misfit + self.refuse_rise)

    def _checked(self, frame: Frame, observation, pose, cov, before, before_cov, judged: bool):
        """(pose, cov, outlier) reported for this frame: contained, refused (``judged``: its shaft
        factors used, no re-initialisation, a covariance) or as computed (module doc)."""
        if self.reinit is None:
            return pose, cov, False
        if self.reinit.outside_pose(pose.matrix()):
            return (*self._contain(before, before_cov), True)
        if judged and self.refuse_rise is not None and before_cov is not None \
                and self._worse_than_before(frame, observation, pose):
            return (*self._refuse(before, before_cov), True)
        return pose, cov, self.reinit.rejected

    def _stamp(self, frame: Frame) -> float:
        self.last_stamp = monotone_stamp(frame.stamp, self.last_stamp, self.fps)
        return self.last_stamp

    def _marginal(self, x: int, pose):
        gtsam = self.gtsam
        try:
            if self.kind == "isam2":
                C = self.smoother.marginalCovariance(x)
            else:
                C = gtsam.Marginals(self.smoother.getFactors(),
                                    self.smoother.calculateEstimate()).marginalCovariance(x)
        except RuntimeError:
            return None
        return left_from_right_cov(pose.matrix(), np.asarray(C))

    def _gated_options(self, features, observation):
        """The options with this frame's marker gate (gating.smoother_gate, the last covariance + one
        motion step; features: the frame's base_features); the configured gate without a covariance."""
        o = self.fopts
        if not self.gate_follows or self.last_cov is None or observation is None or not len(observation.markers):
            return o
        points = features.transformed(self.last.matrix()).points
        return dataclasses.replace(o, marker_gate=smoother_gate(points, self.K, self.last_cov + self.motion_cov, o))

    def _start_up(self, k: int, shaft: list, markers: list, x: int, init=None):
        """Initial value of the first frame with detections: Levenberg-Marquardt on
        that frame's factors + the hand-eye prior (E_0, the prior's spread; the window's
        first-frame prior too). Not a prior at the current estimate: a re-initialisation
        follows a run-away estimate, which would pull the fresh start back to itself.
        iSAM2 makes undamped Gauss-Newton steps, which from a hand-eye error of several
        mm / deg overshoot into a wrong data association.
        ``init``: the initial value (the start-up search's mode) when it is not
        the prior's centre: the search picks the basin, the prior keeps its say."""
        gtsam = self.gtsam
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.start_up_iterations)
        # damping scaled by the Hessian's diagonal: far from the data every pixel sits
        # in the robust kernel's tail, where the square-root residual's Gauss-Newton
        # step overshoots ~2x and lambda * I (up to 1e5) cannot shorten it enough
        params.setDiagonalDamping(True)
        params.setlambdaUpperBound(1e12)
        pose = self.last if init is None else init
        # without a search the markers wait for the shaft stage (their association needs
        # the shaft's pose); the search's mode already explains them: one stage, or the
        # shaft-only stage would let the prior pull the unseen along-shaft slide back
        staged = init is None and bool(shaft) and bool(markers)
        for stage in ([shaft, shaft + markers] if staged else [shaft + markers]):
            g = gtsam.NonlinearFactorGraph()
            g.add(gtsam.PriorFactorPose3(x, gtsam.Pose3(self.E0), self.prior_noise))
            for f in stage:
                g.add(f)
            v = gtsam.Values()
            v.insert(x, pose)
            if self.bias:           # pixel sets are on (x, b) (polar lines not yet): b at its prior
                j = k // self.fopts.edge_bias_period
                g.add(bias_prior_factor(j, self.fopts.edge_bias_sigmas))
                v.insert(bias_key(j), np.zeros(BIAS_DIM))
            try:
                pose = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize().atPose3(x)
            except RuntimeError:
                break
        return pose

    def _factors(self, frame: Frame, observation, right, t: float):
        """This frame's (shaft factors, marker factors, pose key); the key is y_t once settled."""
        if self.start_stamp is None and self.started:   # start_up=False, or after a refusal
            self.start_stamp = t
        if not self.settled and self.start_stamp is not None and t - self.start_stamp >= self.settle:
            self.settled = True
        x = self.gtsam.symbol("y", self.k) if self.settled else key(self.k)
        F = base_features(self.ctx.robot, frame.q)
        shaft, markers = stereo_factor_groups(self.k, frame.q, observation, right, self.ctx, self.K,
                                              self._gated_options(F, observation), self.E0, pose_key=x,
                                              line_bias=self.settled, features=F)
        return shaft, markers, x

    def _open_bias_block(self, k: int, t: float, graph, values, stamps) -> float:
        """With the edge-bias state, open vector j = k // n at its block's first frame (or
        the window's): its prior, or phi times vector j - 1's estimate and the transition.
        Returns the window timestamp of this frame's variables (the block's first
        frame's with the edge-bias state, so that the block's variables leave together)."""
        if not self.bias:
            return t
        j = k // self.fopts.edge_bias_period
        if k % self.fopts.edge_bias_period == 0 or self.bias_stamp is None:
            b0 = np.zeros(BIAS_DIM)
            dt = None if self.bias_stamp is None else t - self.bias_stamp
            if dt is not None:
                b0 = transition(dt, self.fopts.edge_bias_tau) * np.asarray(
                    self.smoother.calculateEstimateVector(bias_key(j - 1)), float)
            for f in edge_bias_factors(j, dt, self.fopts):
                graph.add(f)
            values.insert(bias_key(j), b0)
            stamps.insert((bias_key(j), t))
            self.bias_stamp = t
        return self.bias_stamp

    # -- Estimator -------------------------------------------------------------------
    def step(self, frame: Frame, observation, right=None) -> Estimate:
        gtsam = self.gtsam
        t_start = time.perf_counter()
        self.k += 1
        k = self.k
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        t = self._stamp(frame)
        shaft, markers, x = self._factors(frame, observation, right, t)
        before, before_cov = self.last, self.last_cov
        found = None
        if self.reinit is not None:   # start-up / re-initialisation: initial value from the search
            found = self.reinit.propose(frame.q, observation, self.last.matrix(), bool(shaft or markers),
                                        self.last_cov)
            if self.reinit.rejected:  # an outlier frame on a good lock: predict through it
                shaft, markers = [], []
            if found is not None:
                found = gtsam.Pose3(found)
                if self.started:      # re-initialisation: start up afresh at the search's mode
                    self._restart()
                    shaft, markers, x = self._factors(frame, observation, right, t)
        stamp = self._open_bias_block(k, t, graph, values, stamps)
        if self.prev_key is None:     # the first frame of the window: the hand-eye prior
            prior = (self.last, self.window_prior) if self.window_prior is not None else \
                (gtsam.Pose3(self.E0), self.prior_noise)    # (after a refusal: the pose before it)
            graph.add(gtsam.PriorFactorPose3(x, *prior))
            self.window_prior = None
        else:
            graph.add(gtsam.BetweenFactorPose3(self.prev_key, x, gtsam.Pose3(), self.motion_noise))
        self.prev_key = x
        if not self.started:
            if markers and not shaft and self.waited < self.start_up_wait:
                markers = []          # no marker association before the shaft has been seen
                self.waited += 1
            if shaft or markers:
                self.last = self._start_up(k, shaft, markers, x, init=found)
                self.started = True
                self.start_stamp = t
        for f in shaft + markers:
            graph.add(f)
        values.insert(x, self.last)
        stamps.insert((x, stamp))
        self.smoother.update(graph, values, stamps)
        pose = self.smoother.calculateEstimatePose3(x)
        if self.kind == "isam2":
            for _ in range(self.iterations):
                # iSAM2 makes one Gauss-Newton step per update: iterate while x_t moves
                if np.max(np.abs(self.last.localCoordinates(pose))) < self.converge_tol:
                    break
                self.last = pose
                self.smoother.update()
                pose = self.smoother.calculateEstimatePose3(x)
        self.last = pose
        cov = self._marginal(x, pose) if self.covariance else None
        pose, cov, outlier = self._checked(frame, observation, pose, cov, before, before_cov,
                                           found is None and bool(shaft))
        self.last_cov = cov
        ms = (time.perf_counter() - t_start) * 1e3
        self.timings_ms.append(ms)
        extra = estimate_extra(cov)
        extra["smoother_ms"] = ms
        extra["outlier"] = int(bool(outlier))
        std = None if cov is None else np.sqrt(np.clip(np.diag(cov), 0.0, None))
        return Estimate(pose.matrix(), std, cov, extra)

    def finish(self):
        return None

    def report(self) -> dict[str, int]:
        """The re-initialisation policy's counts (:meth:`SearchInit.report`) and the updates refused."""
        return {**(self.reinit.report() if self.reinit is not None else {}), "refused_updates": self.refused}
