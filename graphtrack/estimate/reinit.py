"""When and where an online estimator (re-)initialises: the global search of
:mod:`graphtrack.estimate.startup` at start-up, after a long stretch without
detections, and when :mod:`graphtrack.estimate.divergence` flags a lost lock.

:class:`SearchInit` is the policy object of the smoother and the particle filter.
``propose(q, observation, E_current, informative)`` is called once per frame and
returns a new initial E (4x4), or None to keep tracking; the adopted search result
(x relative to E_ref = the hand-eye prior, and its elite covariance) is ``result``.

- Start-up, the first informative frame (shaft or markers): the search over
  N(E_current, diag(spread^2)) (spread = (b m, w rad) per axis); its mode is
  adopted at once (nothing is locked yet).
- Re-initialisation: the same search around the current estimate, its prior
  term the hand-eye prior N(0, diag(spread^2)); a mode x_c outside the hand-eye
  prior (|x_c / spread|^2 > ``prior_gate``, chi^2_6's 99.9 % point: the lumped
  error never leaves it) is rejected.
- After a gap (an informative frame after ``gap`` or more frames without one)
  on which the prediction explains little (misfit above the monitor's
  threshold, also at the search's coarse pixel sigma ``COARSE_SIGMA``: the tool
  moved while unseen) nothing is locked: x_c becomes a candidate for the test
  below, without the lock's covariance gate, and the window challenge restarts (8
  frames after the gap). One frame cannot decide: the tool re-enters an edge at a
  time, and a mode fit to one line is set by the prior along what that line does not
  see (docs/decisions/after-a-gap.md). Nor does the estimator take such frames: until a
  frame is explained again, one it does not explain is an outlier frame unless the
  ``confirm`` before it were (an occluder's edge is not the tool's; every (confirm + 1)-th
  is used, so a tool that moved while unseen is re-acquired). A prediction that still
  fits keeps its lock.
- When the divergence monitor fires, a lock exists that may be right (a partial
  or full occlusion also raises the misfit): x_c becomes a *candidate*, adopted
  only after a sequential likelihood-ratio test over the next ``confirm``
  informative frames with the candidate held fixed:

      Lambda = sum_t [log P(z_t | E(x_c)) - log P(z_t | E_t^current)] > confirm * margin

  and the candidate's own mean misfit (:func:`graphtrack.estimate.divergence.misfit`)
  under the monitor's threshold while the current estimate's stays above it (a
  lock that recovers by itself, e.g. as an occluder slides out, is kept), and the
  candidate still ahead on the last of those frames; the search then runs again on
  that frame around x_c and its mode is adopted. A single frame cannot decide (an
  occluder's edges can win one; as the tool moves and the occluder does not, they lose).
  The test has that power only once the tool has moved: it runs on (its threshold
  becoming frames * margin) until x_c's shaft lines, x_c fixed and the readings
  changing, have moved ``min_motion`` px since its first frame (max over the edges of
  |d rho| + |d theta| times the half image diagonal; default 2 * 3 * 2 px, twice the
  outlier floor, beyond which a static occluder's edges stop counting), or ``gap`` frames.
  A confirmed candidate is vetoed when the lock's *evidence*, the latest ``EVIDENCE``
  frames the estimate explained (misfit <= ``lock_threshold``), scores it below the
  current estimate by more than ``margin`` nats per frame: with E nearly constant, such
  a mode is an occluder's (docs/decisions/lock-evidence.md). None is kept across an
  adoption or ``gap`` frames that showed nothing of the tool at the estimate (no
  detections, or none it explains: misfit >= ``BLIND_MISFIT``); E moves with the arm.
- Innovation gate: while *locked* (``lock_frames`` consecutive frames the estimator
  used were explained, misfit <= ``lock_threshold``; before a lock, a frame with a
  misfit between that and the threshold neither extends nor ends one; ``gap`` frames
  without detections end it, as E drifts with the arm while the tool is unseen,
  docs/decisions/lock-after-a-gap.md), a frame the lock does not explain as well as
  those (misfit above ``lock_threshold``) is an outlier frame (``rejected``): the
  estimator predicts through it (docs/decisions/gate-at-lock-threshold.md); the monitor
  still sees its misfit, and the candidate test above replaces a lost lock. While
  locked, a candidate must also pass the lock's covariance gate
  (:meth:`SearchInit.near_lock`: E is nearly constant, so a well-explained lock
  does not jump 10 mm to an occluder's edges; the gate never closes below
  ``LOCK_FLOOR`` of the prior's spread, so a lock can still be corrected by a
  few mm); it opens after ``gap`` outlier frames in a row (such a lock may be wrong).
- Prior guard: an estimate outside the hand-eye prior's region (as the
  ``prior_gate`` above) has run away (the lumped error never leaves it): the
  search is run around the prior's centre and its mode adopted at once.
- Window challenge (one frame rarely decides between two modes; the modes of
  different frames disagree as the tool moves): after 8 frames used since the last
  start, the search runs on ``window`` frames (0: none; the smoother's 6) spread over
  those frames, maximising sum_k log P(z_k | E(x)) + the hand-eye prior. Its mode x_w
  is adopted (keeping the count: one challenge per start) when it lies outside the
  current estimate's covariance gate and

      Lambda = sum_k [log P(z_k | E(x_w)) - log P(z_k | E(x_k))] > window * margin

  (x_k: the estimate on frame k; docs/decisions/window-challenge.md).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from graphtrack.estimate.divergence import DivergenceMonitor, misfit
from graphtrack.estimate.pf.projection import project
from graphtrack.estimate.prior_region import PRIOR_GATE
from graphtrack.estimate.options import SEARCH_STD_B, SEARCH_STD_W
from graphtrack.estimate.startup import SIGMAS, Scorer, SearchResult, global_search
from graphtrack.estimate.window_challenge import HISTORY, scheduled, window_search
from graphtrack.geometry.se3 import bw_to_matrix, invert, matrix_to_bw

#: a frame whose misfit at the estimate reaches this shows nothing of the tool there (as no detections)
BLIND_MISFIT = 0.95
#: a lock's covariance gate is never tighter than this fraction of the search spread
LOCK_FLOOR = 0.1
#: px, the pixel sigma at which a prediction after a gap is judged (the search's second stage)
COARSE_SIGMA = SIGMAS[1]
#: explained frames kept as the lock's evidence, which a candidate must not contradict
EVIDENCE = 5


@dataclass
class _Candidate:
    result: SearchResult
    llr: float = 0.0          # summed log-likelihood ratio candidate - current (nats)
    misfits: float = 0.0      # summed misfit of the candidate
    current: float = 0.0      # summed misfit of the current estimate
    frames: int = 0
    first: np.ndarray | None = None   # (2, 2) its shaft lines (rho px, theta rad) on the first test frame
    motion: float = 0.0       # px, the most those lines have moved since (module doc)


class SearchInit:
    """Start-up / re-initialisation policy (module doc). ``count``: searches adopted;
    ``searches``: searches run."""

    def __init__(self, ctx, spread=(SEARCH_STD_B, SEARCH_STD_W), gap: int = 30, gate_scale: float = 1.0,
                 markers: bool = True, margin: float = 5.0, seed: int = 0, monitor: bool = True,
                 n: int = 2048, confirm: int = 5, prior_gate: float = PRIOR_GATE,
                 lock_threshold: float = 0.25, lock_frames: int = 10, innovation_gate: bool = True,
                 motion_cov: np.ndarray | None = None, window: int = 0, min_motion: float | None = None,
                 **scorer_options):
        b, w = spread
        self.spread = np.array([b] * 3 + [w] * 3, float)
        self.gap = int(gap)
        self.margin = float(margin)
        self.confirm = int(confirm)
        self.prior_gate = float(prior_gate)
        self.E_ref = np.asarray(ctx.handeye, float)
        self.scorer = Scorer(ctx, markers=markers, gate_scale=gate_scale, **scorer_options)
        self.n = int(n)
        self.rng = np.random.default_rng(seed)
        self.since = None            # informative frames: None before the first, else frames since
        self.count = self.searches = self.challenges = self.switches = 0
        self.judged = self.explained = 0   # frames scored at the prediction; of those, explained (misfit <= threshold)
        self.result = None           # the adopted SearchResult (x relative to E_ref)
        self.candidate: _Candidate | None = None
        self.monitor = DivergenceMonitor() if monitor else None
        self.lock_threshold = float(lock_threshold)
        self.innovation_gate = bool(innovation_gate)
        o = self.scorer.shaft_options
        self.min_motion = (2.0 * o["pixel_outlier_sigmas"] * o["pixel_sigma"] if min_motion is None
                           else float(min_motion))   # px (module doc)
        self.half_diagonal = 0.5 * float(np.hypot(ctx.camera.width, ctx.camera.height))
        self.lock_run = 0            # consecutive frames used and explained (misfit <= lock_threshold)
        self.lock_frames = int(lock_frames)
        self.rejected = False        # this frame is an outlier frame (module doc): predict through it
        self.misfit = float("nan")   # this frame's misfit at the estimate it was given (nan: not scored)
        self.rejections = 0          # outlier frames so far
        self.guarded = 0             # prior-guard re-initialisations so far
        self.unused = 0              # frames since the estimator last used a frame
        self.reject_run = 0          # consecutive outlier frames
        self.motion_cov = None if motion_cov is None else np.asarray(motion_cov, float)
        self.window = int(window)    # frames of the window challenge (0: no challenge)
        self.history: deque = deque(maxlen=HISTORY)   # (q, observation, loglik at the estimate) of frames used
        self.blind = 0               # frames in a row the estimate saw nothing of (no detections, or none explained)
        self.used = 0                # frames used since the last start (the challenge's schedule)
        self.evidence: deque = deque(maxlen=EVIDENCE)   # (q, observation) of the latest frames explained
        self.vetoed = 0              # candidates the lock's own frames refused
        self.reentry = False         # after a gap, no frame explained since (module doc)

    def report(self) -> dict[str, int]:
        """The policy's counts over the run: metrics.json's ``estimator_report`` (docs/sequence-format.md)."""
        return {"searches": self.searches, "adopted": self.count, "divergence_alarms": self.monitor.fired
                if self.monitor is not None else 0, "outlier_frames": self.rejections, "vetoed": self.vetoed,
                "prior_guard": self.guarded, "window_challenges": self.challenges, "window_switches": self.switches,
                "frames_judged": self.judged, "frames_explained": self.explained}

    def _x(self, E: np.ndarray) -> np.ndarray:
        return matrix_to_bw(np.asarray(E, float) @ invert(self.E_ref))

    def _adopt(self, res: SearchResult, keep_schedule: bool = False) -> np.ndarray:
        """Adopt a search result: forget the current estimate (:meth:`_forget`), keeping the
        challenge's count when ``keep_schedule`` (a switch by the challenge); E (4x4)."""
        used = self.used
        self._forget()
        if keep_schedule:
            self.used = used
        self.count += 1
        self.result = res
        return bw_to_matrix(res.x) @ self.E_ref

    def _search(self, q, observation, x_cur, prior_centre=None) -> SearchResult:
        self.searches += 1
        return global_search(lambda x, s: self.scorer(q, observation, x, s), x_cur, self.spread, self.rng,
                             n=self.n, prior_centre=prior_centre)

    def _test(self, q, observation, ll_cur: float, m_cur: float, x_cur: np.ndarray) -> np.ndarray | None:
        """One frame of the candidate's sequential likelihood-ratio test (module doc) against
        the current estimate x_cur (its log-likelihood ll_cur and misfit m_cur on this frame)."""
        c = self.candidate
        xc = c.result.x
        ll_c, floor = self.scorer.with_floor(q, observation, xc)
        m = misfit(ll_c, floor)
        c.llr += ll_c - ll_cur
        c.misfits += m if np.isfinite(m) else 1.0
        c.current += m_cur if np.isfinite(m_cur) else 0.0
        c.frames += 1
        self._track_motion(c, q)
        if c.frames < self.confirm or (c.motion < self.min_motion and c.frames < self.gap):
            return None
        threshold = self.threshold
        still_lost = c.current / c.frames > threshold
        if still_lost and c.llr > c.frames * self.margin and c.misfits / c.frames < threshold \
                and ll_c - ll_cur > self.margin:
            if self._contradicts_evidence(xc, x_cur):
                self.vetoed += 1
            else:   # confirmed: the mode is searched afresh on this frame, around the candidate
                return self._adopt(self._search(q, observation, xc, prior_centre=np.zeros(6)))
        self.candidate = None
        return None

    def _contradicts_evidence(self, xc: np.ndarray, x_cur: np.ndarray) -> bool:
        """The candidate xc explains the lock's evidence (the latest frames the estimate
        explained, none across a gap, an adoption or ``gap`` blind frames) worse than x_cur
        by more than ``margin`` nats per frame: E is nearly constant, so a mode that the
        frames before a run of unexplained ones contradict is an occluder's, not the tool's."""
        if not self.evidence:
            return False
        X = np.stack([xc, x_cur])
        ll = sum(self.scorer(q, o, X) for q, o in self.evidence)
        return bool(ll[0] - ll[1] < -len(self.evidence) * self.margin)

    def _track_motion(self, c: _Candidate, q) -> None:
        """Update how far the candidate's projected shaft lines have moved from their
        first test frame (module doc), px."""
        h = project(self.scorer.frame_geometry(q), self.scorer.K, np.asarray(c.result.x, float)[None])
        if not bool(h.valid[0]):
            return
        lines = np.stack([h.rho[:, 0], h.theta[:, 0]], -1)
        if c.first is None:
            c.first = lines
            return
        d = np.abs(lines - c.first)
        c.motion = max(c.motion, float(np.max(d[:, 0] + d[:, 1] * self.half_diagonal)))

    @property
    def locked(self) -> bool:
        """A lock: the last ``lock_frames`` frames used were explained (misfit <= lock_threshold)."""
        return self.lock_run >= self.lock_frames

    def outside(self, x: np.ndarray) -> bool:
        """x (relative to E_ref) lies outside the hand-eye prior's region (module doc)."""
        return bool(np.sum((np.asarray(x, float) / self.spread) ** 2) > self.prior_gate)

    def outside_pose(self, E: np.ndarray) -> bool:
        """E (4x4) lies outside the hand-eye prior's region (module doc)."""
        return self.outside(self._x(E))

    def start_over(self) -> None:
        """The estimator dropped its estimate: the next informative frame is a start-up
        (searched, its mode adopted at once); nothing is locked or pending."""
        self._forget()
        self.since = None

    def _forget(self) -> None:
        """Drop what was learnt about the current estimate (an adoption or a start-over):
        the monitor, a pending candidate, the lock and the challenge's history."""
        if self.monitor is not None:
            self.monitor.reset()
        self.candidate = None
        self.rejected = False
        self.unused = self.lock_run = self.reject_run = self.blind = 0
        self.reentry = False
        self.evidence.clear()
        self._restart_challenge()

    def _restart_challenge(self) -> None:
        """The window challenge's schedule starts afresh: its history is emptied."""
        self.history.clear()
        self.used = 0

    def propose(self, q, observation, E_current: np.ndarray, informative: bool,
                cov: np.ndarray | None = None) -> np.ndarray | None:
        """A new initial E (4x4) or None (module doc); ``cov``: the current estimate's left
        (b, w) covariance (the lock's covariance gate; None: no gate)."""
        self.rejected, self.misfit = False, float("nan")
        self.unused += 1
        if not informative:
            self.blind += 1
            if self.since is not None:
                self.since += 1
            return None
        x_cur = self._x(E_current)
        if self.since is None:                      # start-up
            self.since = 0
            return self._adopt(self._search(q, observation, x_cur))
        if self.outside(x_cur):                     # prior guard: a run-away estimate
            self.since = 0
            self.guarded += 1
            return self._adopt(self._search(q, observation, np.zeros(6)))
        ll_cur, floor = self.scorer.with_floor(q, observation, x_cur)
        m_cur = self.misfit = misfit(ll_cur, floor)
        self.judged += bool(np.isfinite(m_cur))
        self.explained += bool(m_cur <= self.threshold)
        self.blind = self.blind + 1 if not m_cur < BLIND_MISFIT else 0
        if self.blind >= self.gap:
            self.evidence.clear()   # the lock's frames are as old as after a gap: E has moved with the arm
        diverged = self.monitor is not None and self.monitor.update_misfit(m_cur)
        # after a gap, until a frame is explained again: the prediction explains nothing here
        self.reentry = (self.since >= self.gap or self.reentry) and not m_cur <= self.threshold \
            and not self._coarse_fit(q, observation, x_cur)
        after_gap = self.since >= self.gap and self.reentry
        if self.since >= self.gap:
            self.lock_run = 0     # a lock from before a gap is stale: it is earned again
            self.evidence.clear()
        self.since = 0
        if after_gap:
            self._restart_challenge()
        self._gate(m_cur, after_gap, (q, observation))
        if self.window and not self.rejected and np.isfinite(ll_cur):
            self.history.append((np.asarray(q, float), observation, ll_cur))
            self.used += 1
            if self.candidate is None and not after_gap and not diverged and scheduled(self.used):
                return self._challenge(x_cur, cov)
        if self.candidate is not None and not after_gap:
            return self._test(q, observation, ll_cur, m_cur, x_cur)
        if not (after_gap or diverged):
            return None
        res = self._search(q, observation, x_cur, prior_centre=np.zeros(6))
        if self.outside(res.x):
            return None
        if self.locked and self.reject_run < self.gap and not self.near_lock(res.x, x_cur, cov):
            return None   # the lock's covariance gate: E does not jump
        self.candidate = _Candidate(res)
        return self._test(q, observation, ll_cur, m_cur, x_cur)

    def misfit_at(self, q, observation, E: np.ndarray) -> float:
        """This frame's misfit (:func:`misfit`) at E (4x4)."""
        return misfit(*self.scorer.with_floor(q, observation, self._x(E)))

    @property
    def threshold(self) -> float:
        """The misfit above which a frame is not explained (the monitor's threshold)."""
        return self.monitor.threshold if self.monitor is not None else 0.5

    def _gate(self, m_cur: float, after_gap: bool, frame: tuple) -> None:
        """The innovation gate (module doc): mark this frame an outlier frame, or count it
        towards the lock (explained: misfit <= lock_threshold; unexplained, above the
        threshold, ends a lock that is not yet established). A lock uses only frames it
        explains as well as those that formed it."""
        if self.innovation_gate and ((self.locked and not after_gap and not m_cur <= self.lock_threshold)
                                     or (self.reentry and self.reject_run < self.confirm)):
            self.rejected = True
            self.rejections += 1
            self.reject_run += 1
            return
        self.unused = self.reject_run = 0
        if np.isfinite(m_cur) and m_cur <= self.lock_threshold:
            self.lock_run += 1
            self.evidence.append(frame)   # (q, observation): the lock's evidence (:meth:`_contradicts_evidence`)
        elif not m_cur <= self.threshold:
            self.lock_run = 0

    def _coarse_fit(self, q, observation, x: np.ndarray) -> bool:
        """The prediction x explains the frame at the search's coarse pixel sigma
        (``COARSE_SIGMA`` px): after a gap, a prediction a few px off (the tool moved
        a little while unseen) is not lost; the estimator converges from it."""
        ll, floor = self.scorer.with_floor(q, observation, x, sigma=COARSE_SIGMA)
        return bool(misfit(ll, floor) <= self.threshold)

    def near_lock(self, x: np.ndarray, x_cur: np.ndarray, cov: np.ndarray | None) -> bool:
        """The covariance gate of a lock: (x - x_cur)^T C^-1 (x - x_cur) <= ``prior_gate``
        with C = cov + n Q + (LOCK_FLOOR spread)^2, n the frames since the lock was last
        used, Q the estimator's motion model per frame (True without a covariance)."""
        if cov is None or self.motion_cov is None or not np.all(np.isfinite(cov)):
            return True
        return self._within(x, x_cur, np.asarray(cov, float) + self.unused * self.motion_cov)

    def _within(self, x: np.ndarray, x_cur: np.ndarray, C: np.ndarray) -> bool:
        """(x - x_cur)^T (C + (LOCK_FLOOR spread)^2)^-1 (x - x_cur) <= ``prior_gate`` (True
        when that matrix is singular): the gates of :meth:`near_lock` and :meth:`_same_mode`."""
        C = C + np.diag((LOCK_FLOOR * self.spread) ** 2)
        d = np.asarray(x, float) - np.asarray(x_cur, float)
        try:
            return bool(d @ np.linalg.solve(C, d) <= self.prior_gate)
        except np.linalg.LinAlgError:
            return True

    def _challenge(self, x_cur: np.ndarray, cov: np.ndarray | None) -> np.ndarray | None:
        """The window challenge (module doc; :mod:`graphtrack.estimate.window_challenge`): a
        new initial E, or None."""
        self.challenges += 1
        self.searches += 1
        res, gain, frames = window_search(self.scorer, self.history, self.window, x_cur, self.spread,
                                          self.rng, self.n)
        if self.outside(res.x) or self._same_mode(res.x, x_cur, cov) or gain <= frames * self.margin:
            return None
        self.switches += 1
        return self._adopt(res, keep_schedule=True)

    def _same_mode(self, x: np.ndarray, x_cur: np.ndarray, cov: np.ndarray | None) -> bool:
        """x lies within the current estimate's covariance gate (cov + (LOCK_FLOOR spread)^2;
        the floor alone without a finite covariance)."""
        finite = cov is not None and np.all(np.isfinite(cov))
        return self._within(x, x_cur, np.asarray(cov, float) if finite else np.zeros((6, 6)))

