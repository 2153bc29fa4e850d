"""A study's options and its cells (one tracking run each); see :mod:`graphtrack.study.plan`."""
from __future__ import annotations

from dataclasses import dataclass, field

STUDY_VERSION = 1
#: Options that change a cell's result: a study folder holds one value of each.
CELL_OPTIONS = ("detector", "weights", "max_frames", "particles", "lag", "smoother", "seed",
                "alpha", "beta", "markers")


@dataclass
class StudyOptions:
    estimators: list[str] = field(default_factory=lambda: ["kinematics", "pf", "smoother", "batch"])
    observations: list[str] = field(default_factory=lambda: ["line-intensities"])
    detector: str = "learned"
    weights: str | None = None
    max_frames: int | None = None
    particles: int = 1000
    lag: float = 1.0
    smoother: str = "isam2"
    seed: int = 0
    alpha: float = 10.0
    beta: float = 0.9
    markers: bool = True
    repeats: int = 1        #: runs (seeds seed .. seed+repeats-1) of each seed-dependent cell

    def cell_options(self) -> dict:
        return {k: getattr(self, k) for k in CELL_OPTIONS}


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

    @property
    def key(self) -> str:
        k = self.estimator if self.observation is None else f"{self.estimator}-{self.observation}"
        return k if self.repeat == 0 else f"{k}.seed{self.options['seed']}"

    @property
    def row(self) -> tuple[str, str]:
        return ("—" if self.observation is None else self.observation, self.estimator)
