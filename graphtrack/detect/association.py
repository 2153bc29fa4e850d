"""Associate candidate lines / segments with the insertion shaft's two edges.

Candidates: lines l_i = (rho_i, theta_i) (undistorted px, rad; see
:mod:`graphtrack.geometry.lines`) with optional segments s_i = (x1, y1, x2, y2)
lying on them (length L_i, midpoint m_i).

With a prediction (the two limb lines (rho_j, theta_j), j = 0, 1, projected
from the current estimate of E):

    d_theta_ij = line_difference(l_i, l_j)[1]               (rad, wrapped)
    d_off_ij   = |cos(theta_j) m_x + sin(theta_j) m_y - rho_j|   (px)
                 (the distance of the candidate's midpoint to the predicted
                 line; |d_rho| of line_difference when no segments are given)
    gate:  |d_theta_ij| <= max_angle  and  d_off_ij <= max_offset
    cost_ij = |d_theta_ij| / max_angle + d_off_ij / max_offset
              + length_weight (1 - L_i / max_i L_i)

Each predicted edge takes at most one candidate, each candidate at most one
edge; the number of gated matches is maximised first, the cost second. For the
usual two predicted edges the choice is joint: with the signed offsets
s_ij = cos(theta_j) m_x + sin(theta_j) m_y - rho_j (in edge 0's normal
direction), a pair (i for edge 0, i' for edge 1) costs

    cost_i0 + cost_i'1 + pair_weight |s_i0 - s_i'1| / max_offset,

since an error in E shifts both limbs alike while a specular streak inside
the shaft or a tissue fold beside it changes the apparent width; with no
gated pair, the best single gated candidate is kept. Otherwise (one predicted
edge, or pair_weight = 0) it is the Hungarian assignment (scipy's
linear_sum_assignment) with ungated pairs at a prohibitive cost.

Extra lines (tissue folds, jaws, specular streaks) outside the gates are
ignored; an edge with no gated candidate (hidden) is
simply absent (k = 1 or 0). Rows of ``predicted_lines`` that are not finite
are skipped. The midpoint offset is used rather than d_rho because rho is
measured at the image origin, where a small angle error becomes a large
offset for lines far from it.

Without a prediction: among candidates with L_i >= min_length, every pair
(i, j) with |d_theta| <= parallel_tol, a separation (mean midpoint-to-other-
line distance) in [min_width, max_width] px and overlapping extents along the
common direction (overlap >= min_overlap of the shorter segment) is a shaft
hypothesis scored by L_i + L_j; the best pair is returned, its two edges
labelled 0, 1 by increasing offset along the first line's normal (a
deterministic but arbitrary labelling: without a prediction nothing tells
which limb is which). No such pair: k = 0 (a lone line is too ambiguous).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from graphtrack.geometry.lines import line_difference, pixel_residual


@dataclass
class AssociationConfig:
    """Gates (rad, px) and the no-prediction pair search; widen the gates when
    the estimate is uncertain (e.g. at start-up or after a tracking loss)."""

    max_angle: float = 0.15      #: rad, gate on |d_theta| to the predicted edge
    max_offset: float = 40.0     #: px, gate on the midpoint's distance to it
    length_weight: float = 0.1   #: prefer longer candidates among gated ones
    pair_weight: float = 2.0     #: penalty on the two edges' differing shifts (0: off)
    # without a prediction
    parallel_tol: float = 0.15   #: rad, max angle between the two shaft edges
    min_width: float = 8.0       #: px, min separation of the two edges
    max_width: float = 400.0     #: px, max separation
    min_overlap: float = 0.3     #: overlap along the edges / shorter segment
    min_length: float = 40.0     #: px, shorter candidates are not considered


@dataclass
class Association:
    """indices: (k,) rows of the candidates; edge_ids: (k,) predicted edge of
    each (sorted by edge id); lines (k, 2); segments (k, 4) (NaN rows when the
    candidates had no segments)."""

    indices: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    edge_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))

    @property
    def k(self) -> int:
        return len(self.indices)


_BIG = 1e6


def _geometry(lines: np.ndarray, segments: np.ndarray | None):
    if segments is None:
        return None, None, None
    seg = np.asarray(segments, float).reshape(-1, 4)
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    return seg, mid, length


def _result(idx, ids, lines, seg) -> Association:
    idx = np.asarray(idx, dtype=int)
    ids = np.asarray(ids, dtype=int)
    order = np.argsort(ids, kind="stable")
    idx, ids = idx[order], ids[order]
    segs = seg[idx] if seg is not None else np.full((len(idx), 4), np.nan)
    return Association(idx, ids, lines[idx].copy(), segs.copy())


def _best_pair(cost, gated, sig, pr, pid, cfg, L, seg) -> Association:
    """Two predicted edges: the best gated pair under the joint cost (module doc),
    else the best single gated candidate."""
    # signed offsets in the first predicted edge's normal direction
    same = np.cos(pr[0, 1]) * np.cos(pr[1, 1]) + np.sin(pr[0, 1]) * np.sin(pr[1, 1]) >= 0
    s0, s1 = sig[:, 0], sig[:, 1] * (1.0 if same else -1.0)
    g0, g1 = np.flatnonzero(gated[:, 0]), np.flatnonzero(gated[:, 1])
    if len(g0) and len(g1):
        pair = (cost[g0, 0][:, None] + cost[g1, 1][None, :]
                + cfg.pair_weight * np.abs(s0[g0][:, None] - s1[g1][None, :]) / cfg.max_offset)
        pair = np.where(g0[:, None] == g1[None, :], np.inf, pair)
        if np.isfinite(pair).any():
            a, b = np.unravel_index(int(np.argmin(pair)), pair.shape)
            return _result([g0[a], g1[b]], pid, L, seg)
    if not gated.any():
        return Association()
    i, j = np.unravel_index(int(np.argmin(np.where(gated, cost, np.inf))), cost.shape)
    return _result([i], [pid[j]], L, seg)


def _gated(L, seg, mid, length, ok, predicted_lines, cfg) -> Association:
    """Candidates matched to the predicted edges (module doc): gated by angle and
    offset, assigned by cost (jointly for two predicted edges)."""
    pred = np.asarray(predicted_lines, float).reshape(-1, 2)
    pid = np.flatnonzero(np.all(np.isfinite(pred), axis=1))
    if len(pid) == 0:
        return Association()
    pr = pred[pid]
    drho, dth = line_difference(L[:, None, 0], L[:, None, 1], pr[None, :, 0], pr[None, :, 1])
    if mid is not None:  # signed offset of each candidate's midpoint from each predicted line
        sig = pixel_residual(mid, pr[:, 0], pr[:, 1]).T
    else:
        sig = drho
    off = np.abs(sig)
    dth = np.abs(dth)
    gated = (dth <= cfg.max_angle) & (off <= cfg.max_offset) & ok[:, None]
    lmax = max(float(np.max(length[ok])), 1e-9)
    cost = (dth / cfg.max_angle + off / cfg.max_offset
            + cfg.length_weight * (1.0 - np.clip(length / lmax, 0.0, 1.0))[:, None])
    cost = np.where(gated, np.nan_to_num(cost, nan=_BIG), _BIG)
    if len(pid) == 2 and cfg.pair_weight > 0:
        return _best_pair(cost, gated, sig, pr, pid, cfg, L, seg)
    rows, cols = linear_sum_assignment(cost.T)  # rows: predicted, cols: candidates
    keep = gated[cols, rows]
    return _result(cols[keep], pid[rows[keep]], L, seg)


def _pair_ok(L, seg, mid, length, cand, cfg) -> np.ndarray:
    """(n, n) bool over candidates ``cand``: near-parallel, a shaft's width apart and
    (with segments) overlapping along each other."""
    Lc, lc = L[cand], length[cand]
    _, dth = line_difference(Lc[:, None, 0], Lc[:, None, 1], Lc[None, :, 0], Lc[None, :, 1])
    good = np.abs(dth) <= cfg.parallel_tol
    if seg is not None:
        m = mid[cand]
        c, s = np.cos(Lc[:, 1]), np.sin(Lc[:, 1])
        dist = np.abs(pixel_residual(m, Lc[:, 0], Lc[:, 1]))        # dist[i, j]: midpoint of j to line i
        width = 0.5 * (dist + dist.T)
        # extents along the direction of line i, (-sin, cos)
        sg = seg[cand]
        tdir = np.stack([-s, c], 1)                                  # (n, 2)
        ta = tdir @ sg[:, :2].T                                      # ta[i, j]: endpoint a of j on i
        tb = tdir @ sg[:, 2:].T
        lo, hi = np.minimum(ta, tb), np.maximum(ta, tb)
        dlo, dhi = np.diag(lo), np.diag(hi)
        overlap = np.minimum(hi, dhi[:, None]) - np.maximum(lo, dlo[:, None])
        shorter = np.minimum(lc[:, None], lc[None, :])
        good &= (width >= cfg.min_width) & (width <= cfg.max_width)
        good &= overlap >= cfg.min_overlap * np.maximum(shorter, 1e-9)
    else:
        drho, _ = line_difference(Lc[:, None, 0], Lc[:, None, 1], Lc[None, :, 0], Lc[None, :, 1])
        width = np.abs(drho)
        good &= (width >= cfg.min_width) & (width <= cfg.max_width)
    np.fill_diagonal(good, False)
    return good


def _unpredicted(L, seg, mid, length, ok, cfg) -> Association:
    """No prediction: the best pair of near-parallel long candidates, labelled 0, 1
    in the order of their offsets along the first one's normal."""
    cand = np.flatnonzero(ok & (length >= cfg.min_length)) if seg is not None else np.flatnonzero(ok)
    if len(cand) < 2:
        return Association()
    good = _pair_ok(L, seg, mid, length, cand, cfg)
    if not good.any():
        return Association()
    lc = length[cand]
    score = np.where(good, lc[:, None] + lc[None, :], -np.inf)
    i, j = np.unravel_index(int(np.argmax(score)), score.shape)
    a, b = int(cand[i]), int(cand[j])
    # label by signed offset along line a's normal
    if mid is not None:
        c, s = np.cos(L[a, 1]), np.sin(L[a, 1])
        oa = c * mid[a, 0] + s * mid[a, 1]
        ob = c * mid[b, 0] + s * mid[b, 1]
    else:
        oa, ob = L[a, 0], L[a, 0] + line_difference(L[b, 0], L[b, 1], L[a, 0], L[a, 1])[0]
    pair = (a, b) if oa <= ob else (b, a)
    return _result(list(pair), [0, 1], L, seg)


def associate(lines: np.ndarray, segments: np.ndarray | None = None,
              predicted_lines: np.ndarray | None = None,
              config: AssociationConfig | None = None,
              scores: np.ndarray | None = None) -> Association:
    """Pick the shaft's edges among candidates (see the module doc).

    lines: (N, 2) (rho, theta); segments: (N, 4) or None; predicted_lines:
    (P, 2) (usually P = 2) or None; scores: (N,) candidate strengths used in
    place of segment lengths (e.g. Hough votes) when segments are None.
    """
    cfg = config or AssociationConfig()
    L = np.asarray(lines, float).reshape(-1, 2)
    seg, mid, length = _geometry(L, segments)
    if length is None:
        length = np.ones(len(L)) if scores is None else np.asarray(scores, float).ravel()
    ok = np.all(np.isfinite(L), axis=1) & np.isfinite(length)
    if mid is not None:
        ok &= np.all(np.isfinite(mid), axis=1)
    if len(L) == 0 or not ok.any():
        return Association()
    if predicted_lines is not None:
        return _gated(L, seg, mid, length, ok, predicted_lines, cfg)
    return _unpredicted(L, seg, mid, length, ok, cfg)
