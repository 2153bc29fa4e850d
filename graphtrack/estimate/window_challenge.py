"""The window challenge's search: one mode for several frames of a moving tool.

One frame rarely decides between two modes; the modes of different frames disagree as
the tool moves. After ``SCHEDULE`` (8) frames used since a start (:func:`scheduled`), the
re-initialisation policy (:class:`graphtrack.estimate.reinit.SearchInit`) runs the global
search of :mod:`graphtrack.estimate.startup` on ``window`` of the frames used since
(evenly spread over its history of at most ``HISTORY``), maximising

    sum_k log P(z_k | E(x)) + log N(x; 0, diag(spread^2))      (x relative to the hand-eye prior)

and scores its mode x_w against the estimates x_k those frames had:

    Lambda = sum_k [log P(z_k | E(x_w)) - log P(z_k | E(x_k))]   (nats).

The policy adopts x_w when it is a distinct mode and Lambda > window * margin
(docs/decisions/window-challenge.md).
"""
from __future__ import annotations

import numpy as np

from graphtrack.estimate.startup import SearchResult, global_search

#: frames used that the window challenge keeps (it draws ``window`` of them)
HISTORY = 16
#: frames used since a start after which the challenge runs
SCHEDULE = (8,)


def scheduled(used: int) -> bool:
    """The window challenge runs once, after 8 frames used since a start: it takes a start
    that settled on a wrong mode to the right one. Later ones mostly switched settled
    estimates to modes the scorer (without the smoother's edge-bias state) prefers and the
    truth does not (docs/decisions/window-challenge.md)."""
    return used in SCHEDULE


def window_search(scorer, history, window: int, x_cur: np.ndarray, spread: np.ndarray, rng,
                  n: int) -> tuple[SearchResult, float, int]:
    """(x_w's search result, Lambda, the number of frames it was scored on) over ``history``
    ((q, observation, log-likelihood at that frame's estimate) per frame used), searched
    around x_cur with max(256, n / 2) hypotheses per stage (module doc)."""
    frames = list(history)
    pick = np.unique(np.linspace(0, len(frames) - 1, min(window, len(frames))).round().astype(int))
    sel = [frames[i] for i in pick]
    res = global_search(lambda x, s: sum(scorer(q, o, x, s) for q, o, _ in sel), x_cur, spread, rng,
                        n=max(256, n // 2), prior_centre=np.zeros(6))
    gain = sum(float(scorer(q, o, res.x)[0]) - ll for q, o, ll in sel)
    return res, float(gain), len(sel)
