"""A study's options and its cells (one tracking run each); see :mod:`graphtrack.study.plan`."""
from __future__ import annotations

from dataclasses import dataclass, field

from graphtrack.detect.options import OBSERVATION, DetectionOptions
from graphtrack.estimate import ESTIMATORS
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.io.topics import TopicSelection
from graphtrack.track import TrackOptions

STUDY_VERSION = 1
#: Options that change a cell's result: a study folder holds one value of each.
CELL_OPTIONS = ("detector", "weights", "max_frames", "particles", "lag", "smoother", "seed",
                "alpha", "beta", "markers", "views", "shaft_end", "search", "edge_bias", "handeye_sigma",
                "arm", "image_topic", "joint_topic", "jaw_topic", "max_joint_gap",
                "right_image_topic", "turn")
#: the value of an option a study.json written before it existed holds
CELL_OPTION_DEFAULTS = {"shaft_end": True, "search": True, "edge_bias": True, "handeye_sigma": None,
                        "arm": None, "image_topic": None, "joint_topic": None, "jaw_topic": None,
                        "max_joint_gap": None, "right_image_topic": None, "turn": True}
#: the mono / stereo axis: stereo (both images where the recording has a right one),
#: mono (left only, ``--mono``), both (every cell twice, the mono one keyed "-mono")
VIEWS = ("stereo", "mono", "both")


def view_flags(views: str) -> list[bool]:
    """The ``stereo`` values of a study's cells for its ``views``."""
    return {"stereo": [True], "mono": [False], "both": [True, False]}[views]


@dataclass
class StudyOptions:
    """estimators x observations: the cells run on every recording (the kinematics
    baseline once per recording); detection, estimation, seed: as in every cell's
    TrackOptions; max_frames: per recording (None: all); repeats: runs (seeds
    seed .. seed+repeats-1) of each seed-dependent cell; views: the mono / stereo
    axis (:data:`VIEWS`); topics: the arm and bag topics read from every recording."""

    estimators: list[str] = field(default_factory=lambda: list(ESTIMATORS))
    observations: list[str] = field(default_factory=lambda: [OBSERVATION])
    detection: DetectionOptions = field(default_factory=DetectionOptions)
    estimation: EstimatorOptions = field(default_factory=EstimatorOptions)
    seed: int = 0
    max_frames: int | None = None
    repeats: int = 1
    views: str = "stereo"
    topics: TopicSelection = field(default_factory=TopicSelection)

    def cell_options(self) -> dict:
        """The CELL_OPTIONS values (flat, as study.json and done.json store them)."""
        d, e, t = self.detection, self.estimation, self.topics
        return {"detector": d.detector, "weights": d.weights, "max_frames": self.max_frames,
                "particles": e.particles, "lag": e.lag, "smoother": e.smoother, "seed": self.seed,
                "alpha": d.alpha, "beta": d.beta, "markers": d.markers, "views": self.views,
                "shaft_end": d.shaft_end, "search": e.search, "edge_bias": e.edge_bias,
                "handeye_sigma": None if e.handeye_sigma is None else [float(v) for v in e.handeye_sigma],
                "arm": t.arm, "image_topic": t.image, "joint_topic": t.joint, "jaw_topic": t.jaw,
                "max_joint_gap": t.joint_gap, "right_image_topic": t.right,
                "turn": d.turn or d.detector != "learned"}   # only the learned net turns its input


@dataclass
class Cell:
    recording: str          # display name (folder name under runs/)
    path: str               # the recording's path
    estimator: str
    observation: str | None  # None for kinematics
    out: str                # the cell's output folder
    options: dict           # StudyOptions.cell_options()
    video: bool = False     # also write overlay.mp4
    repeat: int = 0         # 0: the study's seed; r: a repeat with seed + r (its options' seed)
    stereo: bool = True     # both images where the recording has a right one (False: --mono)

    @property
    def _mono_suffix(self) -> str:
        """"-mono" for the mono cells of a study over both views (none otherwise)."""
        return "-mono" if not self.stereo and self.options.get("views") == "both" else ""

    @property
    def key(self) -> str:
        k = self.estimator if self.observation is None else f"{self.estimator}-{self.observation}"
        k += self._mono_suffix
        return k if self.repeat == 0 else f"{k}.seed{self.options['seed']}"

    @property
    def row(self) -> tuple[str, str]:
        est = self.estimator + (" (mono)" if self._mono_suffix else "")
        return ("—" if self.observation is None else self.observation, est)

    def track_options(self) -> TrackOptions:
        """The cell's TrackOptions (one seed for the observation draws and the estimator)."""
        o = self.options
        return TrackOptions(
            estimator=self.estimator, observation=self.observation or OBSERVATION,
            detection=DetectionOptions(detector=o["detector"], weights=o["weights"], alpha=o["alpha"],
                                       beta=o["beta"], markers=o["markers"], shaft_end=o["shaft_end"],
                                       turn=o["turn"]),
            estimation=EstimatorOptions(particles=o["particles"], seed=o["seed"], lag=o["lag"],
                                        smoother=o["smoother"], search=o["search"], edge_bias=o["edge_bias"],
                                        handeye_sigma=None if o.get("handeye_sigma") is None
                                        else tuple(o["handeye_sigma"])),
            seed=o["seed"], stereo=self.stereo)

    def topics(self) -> TopicSelection:
        """The arm and bag topics the cell reads."""
        o = self.options
        return TopicSelection(arm=o["arm"], image=o["image_topic"], joint=o["joint_topic"], jaw=o["jaw_topic"],
                              joint_gap=o["max_joint_gap"], right=o["right_image_topic"])
