"""Recordings in, trajectories out: the sequence format (docs/sequence-format.md).

- :func:`open_recording` -> :class:`Recording` (bag or plain-folder form), streaming frames;
- :func:`load_handeye` / :func:`save_handeye` (handeye.yaml, mm <-> m);
- :func:`read_labels` / :func:`write_labels` (labels.csv);
- :class:`TrajectoryWriter` / :func:`read_trajectory` (trajectory.csv, .tum, truth.csv);
- :func:`write_bag` / :func:`write_folder` (what the simulator writes).
"""
from graphtrack.io.bag import BagSource
from graphtrack.io.bag_write import write_bag
from graphtrack.io.folder import FolderSource, write_folder
from graphtrack.io.handeye import load_handeye, save_handeye
from graphtrack.io.labels import read_labels, write_labels
from graphtrack.io.recording import Recording, open_recording
from graphtrack.io.trajectory import COLUMNS, TrajectoryRow, TrajectoryWriter, read_trajectory

__all__ = ["BagSource", "COLUMNS", "FolderSource", "Recording", "TrajectoryRow", "TrajectoryWriter",
           "load_handeye", "open_recording", "read_labels", "read_trajectory", "save_handeye",
           "write_bag", "write_folder", "write_labels"]
