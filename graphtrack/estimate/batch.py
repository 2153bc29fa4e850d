"""Offline factor-graph refinement of E_t over a whole recording.

Same graph as the online smoother (:mod:`graphtrack.estimate.smoother`):
prior on frame 0 at E_0, a BetweenFactorPose3 between every pair of
consecutive frames (always, so gaps in the detections stay solvable), each
frame's robust detection factors but the online smoother's outlier frames' (below; both images' in stereo,
:mod:`graphtrack.estimate.stereo`), and the edge-bias vectors (one per
``edge_bias_every`` frames; the pixel sets and the polar models' lines are on
them from the first frame) with their Gauss-Markov chain
(:mod:`factors.edge_bias`). ``step`` only records the frame's readings
and observation and returns a provisional estimate (the previous one: E_0 at
first, or the online smoother's when ``provisional="smoother"``, the default,
with its std: the tracking pipeline gates the detector with the provisional
estimate's std, so the batch refines exactly the detections the online
smoother saw; without the std every frame had the widest gate). A frame the
online smoother flagged an outlier frame (its ``outlier`` column: a good lock
did not explain it, an occluder's edges near the shaft; its detections drove
the estimate out of the hand-eye prior's region; or its update there explained
the frame worse than the pose before it) gets no detection factors here
either, only its motion (and on frame 0 prior) factors, and 1 in the
``outlier_online`` column: over the whole recording such frames otherwise pull
every E_t towards the occluder (docs/decisions/batch-skips-outlier-frames.md). ``finish``
runs Levenberg-Marquardt over all frames (:mod:`graphtrack.estimate.lm`,
gtsam's iteration driven from Python so that the factor callbacks see the
Values without pybind11 copying it into each one), initialised from the
provisional estimates, and returns the refined Estimates with the marginal
covariance of each E_t in the left (b, w) perturbation (``covariance=True``;
computed with one sparse block-tridiagonal pass over blocks of frames, O(n)).

Defaults (start from the online smoother, relative tolerance 1e-3; each LM
iteration relinearises every frame's Python factors) and their measurements:
docs/decisions/python-lm-for-batch.md.
"""
from __future__ import annotations

import time

import gtsam
import numpy as np

from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.estimate.base import STD_COLUMNS, Estimate, monotone_stamp
from graphtrack.estimate.options import MOTION_SIGMA_B, MOTION_SIGMA_W, PRIOR_SIGMA_B, PRIOR_SIGMA_W
from graphtrack.io.frame import Frame
from graphtrack.io.context import TrackingContext
from graphtrack.estimate.lm import levenberg_marquardt
from graphtrack.estimate.graph import (edge_bias_factors, estimate_extra, gaussian_bw, key,
                                       left_from_right_cov, split_options)
from graphtrack.estimate.stereo import stereo_frame_factors
from factors.edge_bias import BIAS_DIM, bias_key
from graphtrack.estimate.prior_region import PRIOR_GATE, prior_distance
from graphtrack.estimate.smoother import FixedLagSmootherEstimator


class BatchEstimator:
    """Levenberg-Marquardt over the whole recording (see the module docstring).

    Options: markers, prior_sigma_b/_w, motion_sigma_b/_w (as
    the smoother), max_iterations, relative_tolerance, covariance,
    provisional ("last" | "smoother"), fps (the time step of frames without a
    stamp, for the edge-bias chain), plus FactorOptions.
    """

    name = "batch"
    uses_observations = True
    offline = True
    stochastic = False
    supported_observations = OBSERVATION_MODELS
    #: std_*, ``kept_online``: 1 where the refined pose left the hand-eye prior's 99.9 % region
    #: (a run-away refinement) and the online smoother's pose, nearer the prior, was kept instead;
    #: ``outlier_online``: 1 where the online smoother flagged the frame (its detections left out)
    extra_columns = STD_COLUMNS + ("kept_online", "outlier_online")

    def __init__(self, ctx: TrackingContext, markers: bool = True,
                 prior_sigma_b: float = PRIOR_SIGMA_B, prior_sigma_w: float = PRIOR_SIGMA_W,
                 motion_sigma_b: float = MOTION_SIGMA_B, motion_sigma_w: float = MOTION_SIGMA_W,
                 max_iterations: int = 30, relative_tolerance: float = 1e-3,
                 covariance: bool = True, provisional: str = "smoother", fps: float = 30.0, **options):
        self.ctx = ctx
        self.fopts, rest = split_options(dict(options, markers=markers))
        self.E0 = np.asarray(ctx.handeye, float)
        self.K = np.asarray(ctx.camera.K, float)
        self.prior_noise = gaussian_bw(self.E0, prior_sigma_b, prior_sigma_w)
        self.prior_sigma = (float(prior_sigma_b), float(prior_sigma_w))
        self.motion_noise = gaussian_bw(self.E0, motion_sigma_b, motion_sigma_w)
        self.max_iterations = int(max_iterations)
        self.relative_tolerance = float(relative_tolerance)
        self.covariance = bool(covariance)
        self.fps = float(fps)
        self.bias = bool(self.fopts.edge_bias)   # pixel sets and polar lines alike
        self.every = self.fopts.edge_bias_period if self.bias else 1
        self.frames: list[tuple[np.ndarray, object, object]] = []   # (q, left obs, right obs)
        self.stamps: list[float] = []
        self.initial: list[np.ndarray] = []
        self.outlier: list[bool] = []   # per frame: the online smoother did not use its detections
        self.online = None
        if provisional == "smoother":
            self.online = FixedLagSmootherEstimator(ctx, markers=markers,
                                                    prior_sigma_b=prior_sigma_b, prior_sigma_w=prior_sigma_w,
                                                    motion_sigma_b=motion_sigma_b,
                                                    motion_sigma_w=motion_sigma_w, covariance=True,
                                                    fps=fps, **options)
        self.stats: dict[str, float] = {}

    def step(self, frame: Frame, observation, right=None) -> Estimate:
        self.frames.append((np.asarray(frame.q, float).copy(), observation, right))
        self.stamps.append(monotone_stamp(frame.stamp, self.stamps[-1] if self.stamps else None, self.fps))
        if self.online is not None:
            provisional = self.online.step(frame, observation, right)
            self.initial.append(np.array(provisional.E, float))
            self.outlier.append(bool(provisional.extra.get("outlier", 0.0)))
            # with its std, which the tracking pipeline's detector gate reads (so the
            # provisional smoother always computes its marginals: ~0.3 ms per frame with
            # iSAM2, 10-15 % with smoother="batch")
            return provisional
        E = self.initial[-1] if self.initial else self.E0
        self.initial.append(np.asarray(E, float))
        self.outlier.append(False)
        return Estimate(np.asarray(E, float).copy())

    # -- the whole-recording graph -----------------------------------------------------
    def build(self):
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k, (q, obs, right) in enumerate(self.frames):
            if k == 0:
                graph.add(gtsam.PriorFactorPose3(key(0), gtsam.Pose3(self.E0), self.prior_noise))
            else:
                graph.add(gtsam.BetweenFactorPose3(key(k - 1), key(k), gtsam.Pose3(), self.motion_noise))
            if not self.outlier[k]:
                for f in stereo_frame_factors(k, q, obs, right, self.ctx, self.K, self.fopts, self.E0):
                    graph.add(f)
            values.insert(key(k), gtsam.Pose3(self.initial[k]))
            if self.bias and k % self.every == 0:     # the bias of frames k .. k + every - 1
                j = k // self.every
                dt = None if k == 0 else self.stamps[k] - self.stamps[k - self.every]
                for f in edge_bias_factors(j, dt, self.fopts):
                    graph.add(f)
                values.insert(bias_key(j), np.zeros(BIAS_DIM))
        return graph, values

    def _chain_marginals(self, graph, result, n: int) -> list[np.ndarray]:
        """Diagonal 6x6 E blocks of the inverse information of the chain (right coordinates).

        Group the frames in blocks of ``every`` (the frames sharing one edge-bias
        vector; one frame per block without the state): block j's state is
        (E_k for its frames [, b_j]) and every factor touches one block or two
        consecutive ones, so the Gauss-Newton information is block tridiagonal
        in the blocks: forward/backward block elimination (Rauch-Tung-Striebel
        form) gives all diagonal blocks of its inverse in O(n); E_k's marginal is
        its 6 x 6 of its block's.
        """
        every = self.every
        nb = (n + every - 1) // every
        frames_in = [min(every, n - j * every) for j in range(nb)]
        dims = [6 * m + (BIAS_DIM if self.bias else 0) for m in frames_in]
        D = [np.zeros((d, d)) for d in dims]
        U = [np.zeros((dims[j], dims[j + 1])) for j in range(nb - 1)]   # block (j, j+1)
        lin = graph.linearize(result)

        def place(kk):   # (block, first coordinate in the block's state, dimension)
            sym = gtsam.Symbol(kk)
            i = int(sym.index())
            if chr(sym.chr()) == "x":
                return i // every, 6 * (i % every), 6
            return i, 6 * frames_in[i], BIAS_DIM

        for i in range(lin.size()):
            gf = lin.at(i)
            if gf is None:
                continue
            H = gf.augmentedInformation()[:-1, :-1]
            spans, at = [], 0
            for kk in gf.keys():
                blk, off, dim = place(kk)
                spans.append((blk, off, slice(at, at + dim), dim))
                at += dim
            for ba, oa, sa, da in spans:
                for bb, ob, sb, db in spans:
                    if ba == bb:
                        D[ba][oa:oa + da, ob:ob + db] += H[sa, sb]
                    elif ba + 1 == bb:
                        U[ba][oa:oa + da, ob:ob + db] += H[sa, sb]
        # forward: S_j = D_j - U_{j-1}^T S_{j-1}^-1 U_{j-1}
        Sinv = [np.linalg.inv(D[0])]
        for j in range(1, nb):
            Sinv.append(np.linalg.inv(D[j] - U[j - 1].T @ Sinv[j - 1] @ U[j - 1]))
        # backward: P_last = S_last^-1, P_j = S_j^-1 + G_j P_{j+1} G_j^T, G_j = S_j^-1 U_j
        P = [None] * nb
        P[nb - 1] = Sinv[nb - 1]
        for j in range(nb - 2, -1, -1):
            G = Sinv[j] @ U[j]
            P[j] = Sinv[j] + G @ P[j + 1] @ G.T
        out = []
        for k in range(n):
            o = 6 * (k % every)
            out.append(P[k // every][o:o + 6, o:o + 6])
        return out

    def report(self) -> dict:
        """The refinement's figures (build / optimise / covariance seconds, iterations, final
        error, frames the online smoother flagged, frames kept at the online pose) and, under
        ``online``, the online smoother's report."""
        out = dict(self.stats)
        if self.online is not None:
            out["online"] = self.online.report()
        return out

    def finish(self) -> list[Estimate]:
        n = len(self.frames)
        if n == 0:
            return []
        t0 = time.perf_counter()
        graph, values = self.build()
        t1 = time.perf_counter()
        res = levenberg_marquardt(graph, values, self.max_iterations, self.relative_tolerance)
        result = res.values
        t2 = time.perf_counter()
        covs = [None] * n
        if self.covariance:
            try:
                covs = self._chain_marginals(graph, result, n)
            except (RuntimeError, np.linalg.LinAlgError):
                covs = [None] * n
        t3 = time.perf_counter()
        self.stats = {"build_s": t1 - t0, "optimize_s": t2 - t1, "covariance_s": t3 - t2,
                      "iterations": float(res.iterations), "error": res.error,
                      "frames_outlier_online": float(sum(self.outlier))}
        out, kept = [], 0
        for k in range(n):
            E = result.atPose3(key(k)).matrix()
            d = prior_distance(E, self.E0, *self.prior_sigma)
            away = d > PRIOR_GATE and prior_distance(self.initial[k], self.E0, *self.prior_sigma) < d
            if away:   # a run-away refinement: the online pose, nearer the prior, is kept
                E, covs[k], kept = self.initial[k], None, kept + 1
            cov = None if covs[k] is None else left_from_right_cov(E, covs[k])
            std = None if cov is None else np.sqrt(np.clip(np.diag(cov), 0.0, None))
            out.append(Estimate(E, std, cov, {**estimate_extra(cov), "kept_online": int(bool(away)),
                                              "outlier_online": int(self.outlier[k])}))
        self.stats["frames_outside_prior"] = float(kept)
        return out
