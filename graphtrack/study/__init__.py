"""Estimator comparison studies (``graphtrack compare``, ``graphtrack demo``, the accuracy benchmark).

- :mod:`.cells`: :class:`StudyOptions` and :class:`Cell` (one tracking run);
- :mod:`.plan`: which cells exist, the study folder, :func:`run_study`;
- :mod:`.execute`: running cells in local processes or Ray tasks;
- :mod:`.report`: the tables and plots read back from the cell folders.
"""
from graphtrack.study.cells import Cell, StudyOptions
from graphtrack.study.plan import run_study
from graphtrack.study.report import format_table

__all__ = ["Cell", "StudyOptions", "format_table", "run_study"]
