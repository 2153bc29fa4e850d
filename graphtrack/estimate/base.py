"""The one streaming interface every estimator implements.

A :class:`~graphtrack.io.frame.Frame` is what a recording yields (raw image + joint readings); the
tracking loop (:mod:`graphtrack.track`) undistorts, detects and builds an
:class:`~graphtrack.detect.base.Observation`, then asks the estimator for the
lumped error E_t:

    est = estimator.step(frame, observation, right)     # -> Estimate

``right`` is the right image's Observation (undistorted RIGHT pixels, the right
camera's K2) when the tracking context is stereo (``ctx.stereo``: the recording
has a right camera and ``--mono`` was not given) and the frame's right image
decoded; otherwise None, and the update is left-only. An estimator that uses
observations scores both images' terms on the same E_t, the right camera's pose
being ``ctx.right_T_left . E`` (:mod:`graphtrack.estimate.stereo`).

Estimators never see ground truth (truth.csv, labels.csv).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import numpy as np

from graphtrack.detect.base import Observation
from graphtrack.io.frame import Frame

#: trajectory.csv columns of an estimator's uncertainty: the standard deviations of
#: the LEFT camera-frame correction E = Exp(xi) . E_hat, xi = (b [m], w [rad]).
STD_COLUMNS = ("std_bx", "std_by", "std_bz", "std_wx", "std_wy", "std_wz")


def monotone_stamp(stamp, previous: float | None, fps: float) -> float:
    """The seconds an estimator files a frame under: its stamp, or (no finite stamp)
    ``previous`` + 1 / fps (0 for the first frame); kept strictly increasing
    (``previous`` + 1 us), so time steps and fixed-lag windows never run backwards."""
    s = float(stamp) if stamp is not None else float("nan")
    if not np.isfinite(s):
        s = 0.0 if previous is None else previous + 1.0 / fps
    if previous is not None and s <= previous:
        s = previous + 1e-6
    return s


@dataclass
class Estimate:
    """The estimator's answer for one frame.

    E: 4x4 camera-from-base lumped-error transform (metres).
    std: six standard deviations of the correction (b in m, w in rad) in the
    estimator's own tangent space, or None when it has no uncertainty.
    cov: the 6x6 covariance behind ``std`` (optional).
    extra: further per-frame columns the estimator wants in trajectory.csv.
    """

    E: np.ndarray
    std: np.ndarray | None = None
    cov: np.ndarray | None = None
    extra: dict[str, float] = field(default_factory=dict)


class Estimator(Protocol):
    """Streaming estimator of E_t: what the tracking loop and the studies use, declared
    as class attributes by every estimator (read from the class, before building it).

    name: the estimator's name in outputs and studies (``--estimator``);
    uses_observations: False when it ignores images (the loop then skips
    undistortion, detection and observation); stochastic: True when its
    estimate depends on the seed (studies repeat it over seeds); offline: True
    when :meth:`finish` replaces every streamed answer (the refined estimates);
    supported_observations: the observation models (``Observation.model``) it
    can score, () for one that uses none; extra_columns: its trajectory.csv
    columns beyond the standard ones (values from ``Estimate.extra`` / ``std``).
    """

    name: ClassVar[str]
    uses_observations: ClassVar[bool]
    stochastic: ClassVar[bool]
    offline: ClassVar[bool]
    supported_observations: ClassVar[tuple[str, ...]]
    extra_columns: ClassVar[tuple[str, ...]]

    def step(self, frame: Frame, observation: Observation | None,
             right: Observation | None = None) -> Estimate:  # pragma: no cover - protocol
        """Consume one frame and its observation (None: no images used; may be empty)
        and, in stereo, the right image's observation (None: left-only update);
        return E_t. The observations' ``model`` names their observation model."""
        ...

    def finish(self) -> list[Estimate] | None:  # pragma: no cover - protocol
        """Called after the last frame. Offline estimators return the refined
        estimates for every frame (which then replace the streamed rows);
        online ones return None."""
        ...

    def report(self) -> dict:  # pragma: no cover - protocol
        """After :meth:`finish`: the run's counts a user reads to judge it (searches,
        re-initialisations, outlier frames, ...), metrics.json's ``estimator_report``;
        {} when there are none."""
        ...
