"""Association of candidate segments with the shaft's two predicted edges."""
from __future__ import annotations

import numpy as np

from graphtrack.detect.association import AssociationConfig, associate
from graphtrack.geometry.lines import line_through


def seg_line(p, q):
    rho, theta = line_through(np.asarray(p, float), np.asarray(q, float))
    return [float(rho), float(theta)], [*p, *q]


def candidates(*pairs):
    lines, segs = zip(*(seg_line(p, q) for p, q in pairs))
    return np.array(lines), np.array(segs, float)


# the shaft: two near-parallel edges ~60 px apart
EDGE0 = ((0.0, 400.0), (600.0, 180.0))
EDGE1 = ((0.0, 470.0), (620.0, 240.0))
PRED, _ = candidates(EDGE0, EDGE1)


def test_picks_true_edges_among_decoys():
    lines, segs = candidates(
        ((100.0, 30.0), (800.0, 100.0)),       # tissue fold, wrong angle
        EDGE1,
        ((0.0, 330.0), (600.0, 110.0)),        # parallel streak 70 px away: outside the gate
        EDGE0,
        ((300.0, 500.0), (500.0, 300.0)),      # jaw
    )
    pred = PRED + np.array([[3.0, 0.02], [-4.0, -0.02]])
    a = associate(lines, segs, pred)
    assert a.edge_ids.tolist() == [0, 1]
    assert a.indices.tolist() == [3, 1]
    np.testing.assert_allclose(a.lines, lines[[3, 1]])
    np.testing.assert_allclose(a.segments, segs[[3, 1]])


def test_decoy_inside_gate_loses_to_closer_candidate():
    lines, segs = candidates(((0.0, 420.0), (600.0, 200.0)), EDGE0)   # decoy 20 px off
    a = associate(lines, segs, PRED[:1])
    assert a.indices.tolist() == [1] and a.edge_ids.tolist() == [0]


def test_hidden_edge_returns_one():
    lines, segs = candidates(EDGE1, ((100.0, 30.0), (800.0, 100.0)))
    a = associate(lines, segs, PRED)
    assert a.k == 1
    assert a.edge_ids.tolist() == [1] and a.indices.tolist() == [0]


def test_one_candidate_between_two_predictions_is_used_once():
    mid = ((0.0, 435.0), (610.0, 210.0))
    lines, segs = candidates(mid)
    a = associate(lines, segs, PRED)
    assert a.k == 1


def test_nothing_in_the_gates():
    lines, segs = candidates(((100.0, 30.0), (800.0, 100.0)))
    assert associate(lines, segs, PRED).k == 0
    assert associate(np.zeros((0, 2)), np.zeros((0, 4)), PRED).k == 0


def test_widened_gates():
    lines, segs = candidates(((0.0, 340.0), (600.0, 120.0)))   # 60 px off edge 0
    assert associate(lines, segs, PRED[:1]).k == 0
    wide = AssociationConfig(max_offset=100.0, max_angle=0.3)
    assert associate(lines, segs, PRED[:1], wide).k == 1


def test_non_finite_prediction_rows_are_skipped():
    lines, segs = candidates(EDGE0, EDGE1)
    pred = PRED.copy()
    pred[0] = np.nan
    a = associate(lines, segs, pred)
    assert a.edge_ids.tolist() == [1] and a.indices.tolist() == [1]


def test_angle_wraparound():
    # a near-vertical edge: theta ~ 0 in the prediction, ~ pi in the candidate
    lines = np.array([[-300.0, np.pi - 0.01]])
    pred = np.array([[300.0, 0.005]])
    a = associate(lines, None, pred)
    assert a.k == 1 and np.isnan(a.segments).all()


def test_without_prediction_best_parallel_pair():
    lines, segs = candidates(
        ((100.0, 30.0), (800.0, 100.0)),
        EDGE1,
        ((300.0, 500.0), (500.0, 300.0)),
        EDGE0,
        ((50.0, 80.0), (90.0, 84.0)),          # short
    )
    a = associate(lines, segs)
    assert sorted(a.indices.tolist()) == [1, 3]
    assert a.edge_ids.tolist() == [0, 1]
    # deterministic labelling, independent of the candidate order
    b = associate(lines[::-1], segs[::-1])
    np.testing.assert_allclose(a.lines, b.lines)


def test_without_prediction_needs_a_pair():
    lines, segs = candidates(EDGE0, ((100.0, 30.0), (800.0, 100.0)))
    assert associate(lines, segs).k == 0
    # parallel but not facing each other (no overlap along the edges)
    lines, segs = candidates(((0.0, 100.0), (200.0, 100.0)), ((400.0, 150.0), (700.0, 150.0)))
    assert associate(lines, segs).k == 0
    # parallel, overlapping, but 2 px apart (one thick line's two sides)
    lines, segs = candidates(((0.0, 100.0), (300.0, 100.0)), ((0.0, 102.0), (300.0, 102.0)))
    assert associate(lines, segs).k == 0


def shifted(edge, d):
    """The edge moved by d px along its normal (cos theta, sin theta)."""
    (rho, theta), _ = seg_line(*edge)
    n = d * np.array([np.cos(theta), np.sin(theta)])
    return tuple(tuple(np.asarray(p) + n) for p in edge)


def test_pair_term_rejects_specular_streak():
    # both predicted edges 8 px off the truth (an error in E shifts both alike);
    # a streak inside the shaft lies 2 px from predicted edge 1, the true edge 8 px
    (r0, t0), _ = seg_line(*EDGE0)
    (r1, t1), _ = seg_line(*EDGE1)
    inward = np.sign(r0 - r1)             # normal direction from edge 1 towards edge 0
    pred_edges = [shifted(EDGE0, 8 * inward), shifted(EDGE1, 8 * inward)]
    pred, _ = candidates(*pred_edges)
    streak = shifted(EDGE1, 10 * inward)
    lines, segs = candidates(EDGE0, streak, EDGE1)
    a = associate(lines, segs, pred)
    assert a.indices.tolist() == [0, 2] and a.edge_ids.tolist() == [0, 1]
    b = associate(lines, segs, pred, AssociationConfig(pair_weight=0.0))
    assert b.indices.tolist() == [0, 1]   # nearest-to-prediction alone takes the streak
