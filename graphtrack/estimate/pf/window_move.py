"""The particle filter's window move: the cloud shifted to the mode of the frames since its start.

E changes by a random walk of 0.025 mm / 1e-4 rad per frame, so over the first few
dozen frames after a start it is all but constant, and the posterior of x given those
frames is

    p(x | z_1..z_k)  ~  N(x; 0, diag(s^2)) . prod_i P(z_i | E(x))

(s the hand-eye prior's spread: the start-up search's, or the filter's initial spread
without a search). Along a direction the images barely see (the slide of the tool
along its shaft, the depth) each frame adds well under a nat, and a cloud that has
shrunk across that valley climbs it only as fast as its spread lets resampling move it
(docs/decisions/robustness-benchmark.md, traced on the tuning recordings): the
evidence is there, the particles are not.

The move, after the ``SCHEDULE``-th (8th and 16th) frame the filter has weighed since
each (re)start (a frame with detections, not an outlier frame): a cross-entropy search
(:func:`graphtrack.estimate.startup.global_search`, one pixel sigma) of

    J(x) = sum_i log P(z_i | E(x)) - 1/2 |x / s|^2

over those frames, its first stage drawn from N(x_bar, 9 C_cloud + diag(``floor``^2))
(x_bar, C_cloud: the cloud's weighted mean and covariance): the cloud's own shape, so
that the draws lie along the valley it spans rather than across it; ``STAGES`` = 6
stages of ``n`` hypotheses, each re-centred on the last one's elite with their
covariance widened 1.5 times, so that the search can walk several cloud spreads along
the valley; the cloud's mean the incumbent. When the best x* beats the mean by
J(x*) - J(x_bar) > ``MIN_GAIN`` = 3 nats (the log posterior ratio of the two points;
3 is where Kass & Raftery's scale puts "strong" evidence, 2 ln B > 6) and lies inside
the search's prior gate, every particle is shifted by x* - x_bar: the cloud keeps its
shape and weights, only its place changes. Nothing here reads anything but the
frames the filter has already used.

A cloud can also sit in the wrong valley: a start-up mode that fit its first frame,
millimetres from the truth, with the truth's valley beyond the cloud's reach and the
likelihood flat (at its outlier floor) in between, so neither resampling nor a search
drawn along the cloud finds it. When the search around the cloud gains too little, a
second one draws its first stage over the prior instead, N(x_bar, diag(s^2 + floor^2))
(:func:`move_target`), and its mode is taken when it beats the mean by more than
``WIDE_MARGIN`` = 5 nats per frame of the window: the smoother's window challenge's
margin for a distinct mode (docs/decisions/window-challenge.md), far above what one
frame's detector noise gives.

A detector can also err by the whole width of the shaft's image, by the same pixels on
every frame: where a shaded shaft meets a background of its own brightness, the edges
are found 1-3 px inside the limbs (docs/decisions/shaded-limbs.md), which the pixel
model reads as a farther shaft, millimetres deeper. The factor graph carries this as
its edge-bias state; the filter has one width offset w (px), by which every
hypothesis's two limb lines are moved towards the shaft's image
(:meth:`graphtrack.estimate.pf.projection.Hypotheses.limb_rho`). At each move, :func:`width_target`
searches the window's joint mode of (x, w) with J gaining the prior term
-1/2 (w / ``WIDTH_SIGMA``)^2 (1.5 px, the factor graph's width spread), and takes it,
shifting the cloud and setting w, only when it beats what the pose alone gained by
more than ``WIDTH_MARGIN`` = 3 nats: a likelihood-ratio test of one more parameter
(2 ln Lambda > 6), so that unbiased edges keep w where it is (a free w would trade
the width's depth information for nothing) and edges off by pixels on every frame,
which cost tens of nats over the window at the true pose, get it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.estimate.startup import global_search

#: nats: the window's mode must beat the cloud's mean by this much to move the cloud
MIN_GAIN = 3.0
#: frames used since a (re)start after which the cloud is moved (as the smoother's challenge)
SCHEDULE = (8, 16)
#: cross-entropy stages of the move's search (docs/decisions/pf-window-move.md: 3 -> 6)
STAGES = 6
#: nats per window frame: the mode of the search over the prior must beat the cloud's mean
#: by this much (module doc; None: no such search)
WIDE_MARGIN: float | None = 5.0
#: px: the prior spread of the edges' width offset the move estimates with the pose
WIDTH_SIGMA = 1.5
#: nats: the joint mode with the width offset free must beat the pose's alone by this much
WIDTH_MARGIN = 3.0


@dataclass
class WindowMode:
    """x (d,): the window's best hypothesis; gain: J(x) - J(x_bar) (nats)."""

    x: np.ndarray
    gain: float


@dataclass
class MoveTarget:
    """x (6,): where the move shifts the cloud's mean, None: no move; gain: J(x) - J(x_bar)
    of that x, or of the mode near the cloud when there is none (nats)."""

    x: np.ndarray | None
    gain: float


def move_target(loglik, frames: int, x_bar: np.ndarray, cloud_cov: np.ndarray, floor: np.ndarray,
                prior_spread: np.ndarray, rng: np.random.Generator) -> MoveTarget:
    """Where the move shifts the cloud's mean (module doc): the mode near the cloud
    (:func:`window_mode`) when it gains more than MIN_GAIN; else (``WIDE_MARGIN`` not None)
    the mode of a search whose first stage covers the prior when it gains more than
    ``frames`` (the window's frames) x WIDE_MARGIN; else no move. Arguments as
    :func:`window_mode`'s."""
    near = window_mode(loglik, x_bar, cloud_cov, floor, prior_spread, rng)
    if near.gain > MIN_GAIN:
        return MoveTarget(near.x, near.gain)
    if WIDE_MARGIN is None:
        return MoveTarget(None, near.gain)
    spread = np.asarray(prior_spread, float)
    wide = window_mode(loglik, x_bar, cloud_cov, floor, spread, rng, first_cov=np.diag(spread ** 2 + floor ** 2))
    return MoveTarget(wide.x, wide.gain) if wide.gain > frames * WIDE_MARGIN else MoveTarget(None, near.gain)


def width_target(loglik, x_bar: np.ndarray, width: float, cloud_cov: np.ndarray, floor: np.ndarray,
                 prior_spread: np.ndarray, rng: np.random.Generator, gain: float) -> np.ndarray | None:
    """(7,): the window's joint mode (x, w) of the pose and the edges' width offset w (px),
    when it beats the pose alone clearly (module doc), else None.

    loglik(X (m, 7)) -> (m,) the frames' summed log-likelihood with each hypothesis's limb
    lines moved w towards the shaft's image; J gains the prior term -1/2 (w / WIDTH_SIGMA)^2.
    The search is :func:`window_mode`'s near the cloud, from (x_bar, width), the first
    stage's spread in w WIDTH_SIGMA; ``gain``: what the pose alone gained
    (:func:`move_target`). Taken when its gain exceeds max(gain, 0) + WIDTH_MARGIN."""
    X = np.append(np.asarray(x_bar, float), float(width))
    sigma = np.append(np.asarray(prior_spread, float), WIDTH_SIGMA)
    m = window_mode(loglik, X, np.pad(np.asarray(cloud_cov, float), (0, 1)), np.append(floor, WIDTH_SIGMA),
                    sigma, rng)
    return m.x if m.gain > max(gain, 0.0) + WIDTH_MARGIN else None


def window_mode(loglik, x_bar: np.ndarray, cloud_cov: np.ndarray, floor: np.ndarray,
                prior_spread: np.ndarray, rng: np.random.Generator, n: int = 512, stages: int = STAGES,
                elite: float = 0.03, first_cov: np.ndarray | None = None) -> WindowMode:
    """The mode of J (module doc) near x_bar (d,) (the pose, d = 6, or with the width offset,
    d = 7): loglik(x (m, d)) -> (m,) the frames' summed log-likelihood; cloud_cov (d, d):
    the cloud's covariance; floor (d,): the first stage's least spread per axis;
    prior_spread (d,): s. The search is
    :func:`graphtrack.estimate.startup.global_search` at one pixel sigma, the cloud's mean
    its incumbent from the first stage; ``first_cov``: the first stage's covariance instead
    of 9 cloud_cov + diag(floor^2)."""
    x_bar = np.asarray(x_bar, float)
    prior_spread = np.asarray(prior_spread, float)
    cloud_cov, floor = np.asarray(cloud_cov, float), np.asarray(floor, float)
    first = 9.0 * cloud_cov + np.diag(floor ** 2) if first_cov is None else np.asarray(first_cov, float)
    if not (np.all(np.isfinite(first)) and np.all(np.isfinite(x_bar))):
        return WindowMode(x_bar, -np.inf)               # a degenerate cloud: no mode, no move
    sd = np.maximum(3.0 * np.sqrt(np.clip(np.diag(cloud_cov), 0.0, None)), floor)  # floors the elite's covariance
    J0 = float(loglik(x_bar[None])[0] - 0.5 * np.sum((x_bar / prior_spread) ** 2))
    res = global_search(lambda x, _sigma: loglik(x), x_bar, sd, rng, n=n, sigmas=(None,) * stages,
                        elite=elite, prior_centre=np.zeros(len(x_bar)), prior_spread=prior_spread, incumbent=x_bar,
                        first_cov=first)
    if not np.isfinite(res.score):
        return WindowMode(x_bar, -np.inf)            # nothing scored: no mode, no move
    return WindowMode(res.x, res.score - J0 if np.isfinite(J0) else np.inf)
