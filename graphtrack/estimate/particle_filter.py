"""The method's particle filter over the lumped error E_t (camera-from-base).

State: x = (b, w) in R^6 (b m, w axis-angle rad), a LEFT camera-frame correction
of the hand-eye prior E_0 = ctx.handeye: E(x) = [R(w) b; 0 1] . E_0 (se3.bw_to_matrix).
A feature X on link j is seen at E(x) . T_1(q~_1) ... T_j(q~_j) . X, the joint
readings' errors lumped into E_t.

Motion: x_t = x_{t-1} + v_t, v_t ~ N(0, diag(s_b^2 I_3, s_w^2 I_3)), s_b =
``motion_std_b`` (m/frame), s_w = ``motion_std_w`` (rad/frame). Prior: x_0 ~
N(0, diag(i_b^2 I_3, i_w^2 I_3)) (``init_std_b`` m, ``init_std_w`` rad).
Update: log w_n += log P(z_t | E(x_n)) (:mod:`graphtrack.estimate.observation_models`,
all particles projected at once by :mod:`graphtrack.estimate.pf.projection`), in log
space; a frame without shaft or markers leaves the weights alone. Markers are the
paper's points: with ``marker_discs`` a detection of a painted disc is first moved to
where the disc's centre projects, by the offset of the disc's image centroid from it at
the filter's estimate (:mod:`graphtrack.estimate.pf.disc_offsets`). When ESS =
1 / sum w_n^2 < ``resample_threshold`` * N: systematic resampling, then roughening
by kernel shrinkage (Liu & West 2001), h = ``roughening``:

    x_n <- a x_n + (1 - a) x_bar + N(0, h^2 Sigma),   a = sqrt(1 - h^2),

x_bar and Sigma the weighted mean and covariance before resampling, the jitter's std
capped per axis at the prior spread. The shrinkage keeps the cloud's mean and
covariance (a^2 Sigma + h^2 Sigma = Sigma): jitter alone would inflate Sigma by
(1 + h^2) per resampling, a random walk along the directions the images barely
constrain (docs/decisions/pf-kernel-shrinkage.md).
Estimate: b = sum w_n b_n, R the chordal L2 mean of R(w_n), E_t = [R b; 0 1] . E_0;
``Estimate.std``/``cov``: the weighted covariance of x. With ``search`` the cloud is
started and re-initialised from the global search (:mod:`graphtrack.estimate.reinit`);
with ``window_move``, after the 8th and 16th frame it weighs since each start it is
shifted whole to the mode of those frames near it or, by 5 nats a frame, over the prior,
and with ``edge_width`` the same move sets the detected edges' width offset w (px; every
hypothesis's limb lines moved w towards the shaft's image) when the frames' joint mode in (x, w)
beats the pose's alone by 3 nats (:mod:`graphtrack.estimate.pf.window_move`).

Defaults (the dVRK tracker's motion model, a wider initial spread, roughening 0.5)
and their measurements: docs/decisions/pf-initial-spread-and-roughening.md,
startup-search.md.
"""
from __future__ import annotations

import numpy as np

from graphtrack.estimate import observation_models as om
from graphtrack.estimate.base import STD_COLUMNS, Estimate
from graphtrack.estimate.options import (INIT_STD_B, INIT_STD_W, MOTION_SIGMA_B, MOTION_SIGMA_W, PARTICLES, SEARCH,
                                         SEARCH_STD_B, SEARCH_STD_W)
from graphtrack.io.frame import Frame
from graphtrack.io.context import TrackingContext
from graphtrack.estimate.gating import marker_gate
from graphtrack.estimate.pf.disc_offsets import DiscOffsets
from graphtrack.estimate.pf.projection import Hypotheses, frame_geometry, project
from graphtrack.estimate.pf.window_move import SCHEDULE, width_target, move_target
from graphtrack.estimate.reinit import SearchInit
from graphtrack.estimate.resampling import (effective_sample_size, normalize_log_weights, shrink_and_jitter,
                                            systematic_resample)
from graphtrack.geometry.se3 import bw_to_matrix, matrix_to_bw, project_to_so3, so3_exp_batch
from graphtrack.robot.features import base_features


class ParticleFilter:
    """Particle filter over x = (b, w) with E(x) = bw_to_matrix(x) . E_0.

    Options (units): particles N; seed; markers (use detected markers);
    motion_std_b (m/frame), motion_std_w (rad/frame); init_std_b (m),
    init_std_w (rad); resample_threshold (fraction of N for ESS);
    roughening h (kernel bandwidth: the jitter std after resampling as a fraction
    of the particle std, with shrinkage towards the mean; 0: off);
    gamma_rho (1/px), gamma_theta (1/rad): polar models; use_edge_ids: pair
    detected and projected edges by Observation.edge_ids instead of the best
    pairing per particle; pixel_sigma (px), pixel_outlier_sigmas,
    pixel_weight: pixel models; band_weight: the weight of a heatmap band's
    pixels (Observation.bands; 1/4: twice the pixel sigma, docs/decisions/band-weight.md),
    in the likelihood and the search; marker_loss (the update's; the search scores markers
    by the paper's om.MARKER_LOSS), marker_gamma (1/px), marker_gate (px; times gate_scale,
    the full-size px per detection px, set by the tracking pipeline as for the smoother); window_move:
    shift the cloud to the mode of the frames since its start after the 8th and 16th
    frame it weighs (:mod:`graphtrack.estimate.pf.window_move`; independent of
    ``search``, which only supplies its prior spread: ``EstimatorOptions(search=False)``,
    the CLI's ``--no-search``, turns both off); marker_discs: move each painted disc's
    detection to its centre's projection before scoring it as a point
    (:mod:`graphtrack.estimate.pf.disc_offsets`; off: the paper's point markers as
    detected); edge_width: the window move may set the edges' width offset (off: 0 px).
    Each Observation carries its own ``model``, which is what is scored.
    """

    name = "pf"
    stochastic = True   #: the estimate depends on ``seed`` (resampling): studies repeat it
    uses_observations = True
    offline = False
    supported_observations = om.OBSERVATION_MODELS
    extra_columns = STD_COLUMNS + ("ess", "outlier")

    def __init__(self, ctx: TrackingContext,
                 particles: int = PARTICLES, seed: int = 0, markers: bool = True, *,
                 motion_std_b: float = MOTION_SIGMA_B, motion_std_w: float = MOTION_SIGMA_W,
                 init_std_b: float = INIT_STD_B, init_std_w: float = INIT_STD_W,
                 resample_threshold: float = 0.5, roughening: float = 0.5,
                 gamma_rho: float = om.GAMMA_RHO, gamma_theta: float = om.GAMMA_THETA,
                 use_edge_ids: bool = False, pixel_sigma: float = om.PIXEL_SIGMA,
                 pixel_outlier_sigmas: float = om.PIXEL_OUTLIER_SIGMAS,
                 pixel_weight: float = om.PIXEL_WEIGHT,
                 marker_gamma: float = om.MARKER_GAMMA, marker_gate: float = om.MARKER_GATE,
                 gate_scale: float = 1.0,
                 pixel_effective_count: float = om.PIXEL_EFFECTIVE_COUNT,
                 band_weight: float = om.BAND_WEIGHT,
                 marker_loss: str = om.PF_MARKER_LOSS, marker_sigma: float = om.MARKER_SIGMA,
                 marker_huber_k: float = om.MARKER_HUBER_K,
                 search: bool = SEARCH, search_std_b: float = SEARCH_STD_B, search_std_w: float = SEARCH_STD_W,
                 search_hypotheses: int = 2048, reinit_gap: int = 30,
                 marker_gate_follows_covariance: bool = False, window_move: bool = True,
                 marker_discs: bool = True, edge_width: bool = True):
        if int(particles) < 1:
            raise ValueError("particles must be >= 1")
        self.ctx = ctx
        self.robot = ctx.robot
        self.K = np.asarray(ctx.camera.K, dtype=float)
        self.E0 = np.asarray(ctx.handeye, dtype=float).copy()
        self.N = int(particles)
        self.use_markers = bool(markers)
        self.rng = np.random.default_rng(seed)
        self.window_move = bool(window_move)       # pf/window_move.py
        self._move_rng = np.random.default_rng([int(seed), 1])   # its own draws: the cloud's stay as they were
        self.window_moves = 0
        self.edge_width = bool(edge_width) and self.window_move
        self.width = 0.0
        self.discs = DiscOffsets(ctx.robot) if marker_discs and markers else None   # pf/disc_offsets.py
        self.motion_std = np.array([motion_std_b] * 3 + [motion_std_w] * 3, dtype=float)
        self.init_std = np.array([init_std_b] * 3 + [init_std_w] * 3, dtype=float)
        self.resample_threshold = float(resample_threshold)
        self.roughening = float(roughening)
        self.shaft_options = dict(gamma_rho=gamma_rho, gamma_theta=gamma_theta,
                                  use_edge_ids=use_edge_ids, pixel_sigma=pixel_sigma,
                                  pixel_outlier_sigmas=pixel_outlier_sigmas,
                                  pixel_weight=pixel_weight,
                                  pixel_effective_count=pixel_effective_count,
                                  band_weight=band_weight)
        if marker_loss not in om.MARKER_LOSSES:
            raise ValueError(f"unknown marker loss {marker_loss!r}")
        self.marker_gamma = float(marker_gamma)
        self.marker_gate = self.configured_gate = float(marker_gate) * float(gate_scale)
        self.gate_scale = float(gate_scale)
        self.gate_follows = bool(marker_gate_follows_covariance)   # estimate/gating.py; off: see its doc
        self.marker_options = dict(loss=marker_loss, sigma=float(marker_sigma),
                                   huber_k=float(marker_huber_k))
        self._buffers: dict = {}
        self._buffers_right: dict = {}   # the right image's pixel buffers (its own sizes)
        self._geometry_cache = None
        self.search_std = np.array([search_std_b] * 3 + [search_std_w] * 3, dtype=float)
        self.search = None
        if search:
            self.search = SearchInit(ctx, (search_std_b, search_std_w), reinit_gap, gate_scale, markers,
                                     seed=seed, n=search_hypotheses, marker_gamma=marker_gamma, marker_gate=marker_gate,
                                     marker_loss=om.MARKER_LOSS, marker_sigma=marker_sigma, marker_huber_k=marker_huber_k,
                                     motion_cov=np.diag(self.motion_std ** 2), **self.shaft_options)
        self.reset()

    # -- state ------------------------------------------------------------------------
    def reset(self, x0: np.ndarray | None = None) -> None:
        """Draw the prior cloud x_n ~ N(x0, diag(init_std^2)), equal weights."""
        centre = np.zeros(6) if x0 is None else np.asarray(x0, float)
        self.x = centre + self.rng.standard_normal((self.N, 6)) * self.init_std
        self.logw = np.full(self.N, -np.log(self.N))
        self.t = 0
        self._window = []     # (q, observation, right) of the frames used since the cloud's start
        self.x_mean = centre.copy()
        self.R_mean = so3_exp_batch(centre[None, 3:])[:, :, 0]
        self.cov = np.diag(self.init_std ** 2)

    @property
    def weights(self) -> np.ndarray:
        return np.exp(self.logw)

    @property
    def E(self) -> np.ndarray:
        """The current estimate of E_t (4x4)."""
        C = np.eye(4)
        C[:3, :3] = self.R_mean
        C[:3, 3] = self.x_mean[:3]
        return C @ self.E0

    def predict(self) -> None:
        """x_n += v_n, v_n ~ N(0, diag(motion_std^2))."""
        self.x += self.rng.standard_normal((self.N, 6)) * self.motion_std

    # -- projection of every hypothesis -----------------------------------------------
    def _frame_geometry(self, q: np.ndarray):
        """:func:`graphtrack.estimate.pf.projection.frame_geometry` of reading q,
        cached for the last q (predicted_lines and step read the same frame); with a
        search, its scorer's cache, which maps by the same E_0 (``ctx.handeye``) and
        scores the same frame."""
        if self.search is not None:
            return self.search.scorer.frame_geometry(q)
        q = np.asarray(q, float)
        key = q.tobytes()
        if self._geometry_cache is None or self._geometry_cache[0] != key:
            self._geometry_cache = (key, frame_geometry(self.robot, q, self.E0))
        return self._geometry_cache[1]

    def _project(self, q: np.ndarray, x: np.ndarray | None = None, right: bool = False,
                 R: np.ndarray | None = None) -> Hypotheses:
        """Every particle's (or state x's) projection into the left image, or with
        ``right`` into the stereo right one (:mod:`graphtrack.estimate.stereo`)."""
        x = self.x if x is None else np.atleast_2d(np.asarray(x, float))
        if right:
            return project(self._frame_geometry(q), self.ctx.right.K, x, self.ctx.right_T_left, R)
        return project(self._frame_geometry(q), self.K, x)

    def hypotheses(self, q: np.ndarray, x: np.ndarray | None = None) -> dict:
        """The shaft and markers of every particle (or of states x (n, 6)) projected: rho, theta
        (n, 2) px/rad, valid (n,), markers (n, M, 2) px, visible (n, M) bool, R (n, 3, 3)."""
        h = self._project(q, x)
        return dict(rho=h.rho.T, theta=h.theta.T, valid=h.valid,
                    markers=np.stack([h.u.T, h.v.T], -1), visible=h.visible.T,
                    R=np.moveaxis(h.R, -1, 0))

    def predicted_lines(self, q: np.ndarray) -> np.ndarray:
        """(2, 2) (rho, theta) of the shaft edges at the current estimate, for a detector's gate."""
        xm = matrix_to_bw(self.E @ np.linalg.inv(self.E0))
        h = self.hypotheses(q, xm[None])
        return np.stack([h["rho"][0], h["theta"][0]], -1)

    # -- the filter step --------------------------------------------------------------
    def log_likelihood(self, q: np.ndarray, observation, x: np.ndarray | None = None,
                       right=None, width=None) -> np.ndarray:
        """log P(z | E(x_n)) (shaft model + markers) for every particle (or states x);
        with the right image's observation ``right`` (stereo context) the sum of both
        images' terms (:mod:`graphtrack.estimate.stereo`); ``width`` (px, scalar or per state):
        the edges' width offset instead of the filter's own (both images share it)."""
        h = self._project(q, x)
        index = None if x is None else 0     # a batch of hypotheses: pair markers at its first
        return self._loglik(h, observation, index=index, width=width) + \
            self._loglik_right(q, x, h, right, index, width)

    def _loglik_right(self, q, x, h: Hypotheses, right, index: int | None = None, width=None) -> np.ndarray | float:
        """The right image's term log P(z_right | right_T_left . E(x_n)), 0 without one."""
        if right is None or not self.ctx.stereo or not self._informative(right):
            return 0.0
        return self._loglik(self._project(q, x, right=True, R=h.R), right, self._buffers_right, index, width)

    def _informative(self, observation) -> bool:
        return observation is not None and (observation.has_shaft
                                            or (self.use_markers and len(observation.markers) > 0))

    def _loglik(self, h: Hypotheses, observation, buffers: dict | None = None,
                index: int | None = None, width=None) -> np.ndarray:
        """log P(z | E) of projected hypotheses h; ``index``: the hypothesis whose marker
        pairing breaks ties (None: the cloud's best particle when h is the cloud)."""
        n = len(h.valid)
        ll = np.zeros(n)
        if observation is None:
            return ll
        if observation.has_shaft:
            ll += om.shaft_loglik(observation, h.limb_rho(self.width if width is None else width),
                                  lambda: h.theta.T, h.valid,
                                  _buffers=self._buffers if buffers is None else buffers, cos_sin=(h.cos.T, h.sin.T),
                                  **self.shaft_options)
        if self.use_markers and len(observation.markers):
            ll += om.marker_loglik_mn(h.u, h.v, h.visible, observation.markers,
                                      self.marker_gamma, self.marker_gate,
                                      estimate_index=(index if index is not None else
                                                      int(np.argmax(self.logw)) if n == self.N else 0),
                                      **self.marker_options)
        return ll + om.shaft_end_loglik(h.end_u, h.end_v, observation)

    def step(self, frame: Frame, observation=None, right=None) -> Estimate:
        q = frame.q
        if self.t > 0:
            self.predict()
        self.t += 1
        h = self._project(q)
        informative = self._informative(observation)
        E_hat = None
        if self.search is not None and self.search.propose(q, observation, self.E, informative,
                                                           self.cov) is not None:
            self._redraw(self.search.result)  # start-up, long gap or divergence: global search (left view)
            self._window = []
            h = self._project(q)
            E_hat = bw_to_matrix(self.search.result.x) @ self.E0
        observation, right = self._disc_centres(q, E_hat, observation, right)
        if self.gate_follows and informative and len(observation.markers):
            self._gate_markers(q)
        rejected = self.search is not None and self.search.rejected   # an outlier frame: predict through it
        if not rejected and (informative or (right is not None and self._informative(right))):
            self.logw = normalize_log_weights(self.logw + self._loglik(h, observation)
                                              + self._loglik_right(q, None, h, right))
            if len(self._window) < max(SCHEDULE):
                self._window.append((q, observation, right))
                if self.window_move and len(self._window) in SCHEDULE and self._move():
                    h = self._project(q)
        w = np.exp(self.logw)
        ess = effective_sample_size(w)
        # estimate: weighted mean of b, chordal mean of R(w)
        self.x_mean, cov = self._moments(w)
        self.R_mean = project_to_so3((h.R.reshape(9, -1) @ w).reshape(3, 3))
        self.cov = cov
        est = Estimate(self.E, std=np.sqrt(np.diag(cov)), cov=cov,
                       extra={**dict(zip(STD_COLUMNS, map(float, np.sqrt(np.diag(cov))))),
                              "ess": ess, "outlier": int(bool(rejected))})
        if ess < self.resample_threshold * self.N:
            self.resample(w, cov)
        return est

    def _disc_centres(self, q, E_hat: np.ndarray, observation, right):
        """Both images' observations with their painted-disc detections moved to the
        discs' centres at the estimate E_hat (None: the filter's E;
        :mod:`graphtrack.estimate.pf.disc_offsets`), where the point markers of the
        likelihood predict them; as they are with ``marker_discs`` off. Pairs within the
        previous frame's marker gate (this frame's is set after it), and the window move
        keeps the moved observations."""
        if self.discs is None:
            return observation, right
        E_hat = self.E if E_hat is None else E_hat
        g, C = self._frame_geometry(q), E_hat @ np.linalg.inv(self.E0)

        def seen(K, C):   # the markers the likelihood sees at E_hat: needed only for point markers among discs
            return project(g, K, np.zeros((1, 6)), C).visible[:, 0] if self.discs.point.any() else None

        observation = self.discs.centre_equivalent(observation, q, E_hat, self.K, self.marker_gate, g.marker_links,
                                                   seen(self.K, C))
        if right is not None and self.ctx.stereo:
            C, K2 = self.ctx.right_T_left @ C, self.ctx.right.K
            right = self.discs.centre_equivalent(right, q, self.ctx.right_T_left @ E_hat, K2, self.marker_gate,
                                                 g.marker_links, seen(K2, C))
        return observation, right

    def _moments(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cloud's weighted mean (6,) and covariance (6, 6) of x under weights w."""
        mean = w @ self.x
        dx = self.x - mean
        return mean, (dx * w[:, None]).T @ dx

    def _move(self) -> bool:
        """Shift the cloud to the mode of the frames since its start when that mode is
        clearly better (:mod:`graphtrack.estimate.pf.window_move`); True when moved."""
        x_bar, cov = self._moments(np.exp(self.logw))
        prior = self.search.spread if self.search is not None else self.init_std
        frames = list(self._window)

        def loglik(X):
            w = X[:, 6] if X.shape[1] > 6 else None
            return sum(self.log_likelihood(q, o, X[:, :6], r, w) for q, o, r in frames)

        floor = self.init_std / 4
        found = move_target(loglik, len(frames), x_bar, cov, floor, prior, self._move_rng)
        x, width = found.x, self.width
        outside = self.search.outside if self.search is not None else (lambda _x: False)
        if self.edge_width:
            joint = width_target(loglik, x_bar, self.width, cov, floor, prior, self._move_rng, found.gain)
            if joint is not None and not outside(joint[:6]):
                x, width = joint[:6], float(joint[6])
        if x is None or outside(x):
            return False          # not clearly better, or outside the prior gate the search keeps
        self.x = self.x + (x - x_bar)
        self.width = width
        self.window_moves += 1
        return True

    def _gate_markers(self, q) -> None:
        """The marker gate of this frame from the predicted cloud's covariance
        (:mod:`graphtrack.estimate.gating`)."""
        if self.use_markers:
            self.marker_gate = marker_gate(base_features(self.robot, q).transformed(self.E).points, self.K,
                                           self.cov + np.diag(self.motion_std ** 2), self.configured_gate,
                                           self.marker_options["sigma"], self.gate_scale)

    def _redraw(self, res) -> None:
        """Redraw the cloud from a search result (:mod:`graphtrack.estimate.reinit`):
        x_n ~ N(res.x, C), C the search's elite covariance with per-axis stds clipped
        to [init_std / 8, init_std], weighted by prior / proposal density."""
        sd = np.sqrt(np.clip(np.diag(res.cov), 0.0, None))
        scale = np.clip(sd, self.init_std / 8, self.init_std) / np.maximum(sd, 1e-300)
        C = scale[:, None] * res.cov * scale[None, :] + np.diag((1e-3 * self.init_std) ** 2)
        L = np.linalg.cholesky(0.5 * (C + C.T))
        z = self.rng.standard_normal((self.N, 6))
        self.x = res.x + z @ L.T
        # importance weights prior / proposal: the search proposes, the prior (the
        # search's hand-eye prior N(0, diag(spread^2))) keeps its say
        self.logw = normalize_log_weights(-0.5 * np.sum((self.x / self.search.spread) ** 2, axis=1)
                                          + 0.5 * np.sum(z * z, axis=1))
        self.cov = C

    def resample(self, w: np.ndarray | None = None, cov: np.ndarray | None = None) -> None:
        """Systematic resampling, then roughening by kernel shrinkage (module doc)."""
        w = np.exp(self.logw) if w is None else w
        mean = w @ self.x
        self.x = self.x[systematic_resample(w, self.rng)]
        self.logw = np.full(self.N, -np.log(self.N))
        if self.roughening > 0 and cov is not None:
            self.x = shrink_and_jitter(self.x, mean, cov, self.roughening, self.init_std, 1e-3 * self.motion_std,
                                       self.rng)

    def finish(self):
        return None

    def report(self) -> dict[str, float]:
        """The search's counts (:meth:`SearchInit.report`), the window moves, the final width offset (px)."""
        return {**(self.search.report() if self.search is not None else {}), "window_moves": self.window_moves,
                "width_offset_px": round(self.width, 3)}
