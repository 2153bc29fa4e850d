"""Estimator comparison studies: every (recording, estimator, observation model) cell.

A study folder DIR holds:

- ``study.json``: the options every cell was run with (refusing to mix: a
  second run with other options raises InputError) and the last request;
- ``runs/<recording>/<estimator>-<observation>/``: one ``graphtrack track``
  output per cell (trajectory.csv, trajectory.tum, metrics.json, ...) and
  ``done.json``, written LAST: a cell with done.json is complete and is not
  recomputed, so an interrupted study continues where it stopped. A cell that
  failed holds ``error.json`` instead (and is retried next time). The
  kinematics baseline ignores the observation model: one cell
  ``runs/<recording>/kinematics/`` per recording;
- ``table.md`` / ``table.csv``: the method's Table I (rows: observation model x
  estimator, columns: recordings, cells: mean (std) 2-D tip error in % of the
  image diagonal), the runtime table (median ms/frame, fps; also
  ``runtime.csv``), every cell's numbers in ``results.csv``, and the errors;
- ``accumulated_error_<recording>.png``: the running mean of the 2-D tip error
  over frames, one curve per cell (the method's Fig. 4).

Repeats (``repeats`` N > 1): a cell whose result depends on the seed (a
stochastic estimator, i.e. the particle filter's resampling, or an observation
model that fits RANSAC lines) is run with seeds seed, seed+1, ..., seed+N-1
(the first in ``<estimator>-<observation>/``, the others in
``<estimator>-<observation>.seed<S>/``) and the tables report the mean over
the N runs, with their spread; results.csv keeps every run. One seed of a
particle filter is one draw: on the benchmark's structured recording, four
filter seeds of line-intensities-polar gave 4.5, 5.9, 9.5 and 6.8 px.

Cells run in local processes (``workers``) or as Ray tasks (``ray_address``),
by :mod:`graphtrack.study.execute`; the tables by :mod:`graphtrack.study.report`.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from graphtrack.detect.observe import SEEDED_MODELS
from graphtrack.errors import InputError
from graphtrack.estimate import estimator_class
from graphtrack.io.run_output import refuse_other_runs
from graphtrack.study.cells import CELL_OPTION_DEFAULTS, CELL_OPTIONS, STUDY_VERSION, Cell, StudyOptions, view_flags
from graphtrack.study.execute import check_ray_address, run_local, run_ray
from graphtrack.study.report import is_done, plot_accumulated, recording_notes, write_tables

# -- which combinations exist -----------------------------------------------------------
def supported_observations(estimator: str) -> tuple[str, ...]:
    """Observation models ``estimator`` scores (its class's ``supported_observations``)."""
    return tuple(estimator_class(estimator).supported_observations)


def seed_dependent(estimator: str, observation: str | None) -> bool:
    """Whether a cell's result depends on the seed: a ``stochastic`` estimator
    (the particle filter) or an observation model that draws RANSAC samples."""
    cls = estimator_class(estimator)
    if not cls.uses_observations:
        return bool(cls.stochastic)
    return bool(cls.stochastic) or observation in SEEDED_MODELS


def recording_names(paths: list[str]) -> list[str]:
    """Unique, readable names for the recordings: folder names, a clash numbered _2, _3, ...
    past every name already taken (``a/rec b/rec c/rec_2``: rec, rec_3, rec_2)."""
    bases = []
    for p in paths:
        base = Path(p).resolve()
        name = base.name if base.is_dir() else base.stem
        bases.append("".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "recording")
    names, taken = [], set()
    for name in bases:
        if name in taken:   # the suffix skips every folder name, so no later one is taken
            k = 2
            while f"{name}_{k}" in taken or f"{name}_{k}" in bases:
                k += 1
            name = f"{name}_{k}"
        taken.add(name)
        names.append(name)
    return names


def plan(paths: list[str], options: StudyOptions, out: Path,
         names: list[str] | None = None) -> tuple[list[Cell], list[str]]:
    """The cells to run, in table order, and notes about skipped combinations.

    names: the recordings' names in the tables and under runs/ (default: folder names).
    """
    cells, notes = [], []
    opts = options.cell_options()
    names = list(names) if names is not None else recording_names(paths)
    # estimators that use no observations (the kinematics baseline): one cell per recording
    blind = [e for e in options.estimators if not estimator_class(e).uses_observations]
    for est in options.estimators:
        if not estimator_class(est).uses_observations:
            continue
        bad = [o for o in options.observations if o not in supported_observations(est)]
        if bad:
            notes.append(f"{est} does not support {', '.join(bad)}: skipped")
    for name, path in zip(names, paths):
        root = out / "runs" / name
        for est in blind:
            cells.append(Cell(name, str(Path(path).resolve()), est, None, str(root / est), opts))
        for obs in options.observations:
            for est in options.estimators:
                if est in blind or obs not in supported_observations(est):
                    continue
                n = options.repeats if seed_dependent(est, obs) else 1
                for stereo in view_flags(options.views):
                    for r in range(n):
                        o = opts if r == 0 else dict(opts, seed=opts["seed"] + r)
                        c = Cell(name, str(Path(path).resolve()), est, obs, "", o, repeat=r, stereo=stereo)
                        c.out = str(root / c.key)
                        cells.append(c)
    return cells, notes


# -- study.json: one set of options per folder ------------------------------------------
def _check_same_options(out: Path, stored: dict, options: StudyOptions) -> None:
    """InputError when ``out`` holds finished cells made with other options than these
    (``stored``: study.json's; an option it predates holds its default). A folder with no
    finished cell takes the new options (e.g. a mistyped topic corrected)."""
    old, new = {**CELL_OPTION_DEFAULTS, **stored}, options.cell_options()
    diff = [k for k in CELL_OPTIONS if old.get(k) != new[k]]
    if not diff or not any((out / "runs").glob("*/*/done.json")):
        return
    what = ", ".join(f"{k}: {old.get(k)!r} there{'' if k in stored else ' (the default: the folder predates it)'}, "
                     f"{new[k]!r} now" for k in diff)
    raise InputError(f"{out}: holds a study made with other options ({what}); "
                     f"use another --out, or the same options to continue it")


def check_study_folder(out: Path, options: StudyOptions, cells: list[Cell]) -> None:
    """Create or check DIR/study.json; refuse a folder made with other options."""
    doc_path = out / "study.json"
    recordings = {c.recording: c.path for c in cells}
    if doc_path.is_file():
        try:
            old = json.loads(doc_path.read_text())
        except (OSError, json.JSONDecodeError):
            raise InputError(f"{doc_path}: unreadable study.json; use another --out or remove it") from None
        _check_same_options(out, old.get("options", {}), options)
        old_recs = old.get("recordings", {})
        clash = [n for n, p in recordings.items() if n in old_recs and old_recs[n] != p]
        if clash:
            raise InputError(f"{out}: recording name {clash[0]!r} there is {old_recs[clash[0]]}, "
                             f"not {recordings[clash[0]]}; use another --out")
        recordings = {**old_recs, **recordings}
    try:
        out.mkdir(parents=True, exist_ok=True)
        doc = {"version": STUDY_VERSION, "options": options.cell_options(),
               "estimators": options.estimators, "observations": options.observations,
               "repeats": options.repeats, "recordings": recordings}
        tmp = doc_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=2))
        os.replace(tmp, doc_path)
    except OSError as e:
        raise InputError(f"{out}: cannot write the study folder ({e.strerror})") from None


# -- the whole study ----------------------------------------------------------------------
def run_study(paths: list[str], out: str | Path, options: StudyOptions, workers: int = 1,
              ray_address: str | None = None, quiet: bool = False, video=None,
              names: list[str] | None = None) -> dict:
    """Run (or continue) a study; write the tables and plots; return the table data
    plus ``ran`` (cells computed now), ``reused`` (cells already done) and ``cells``.

    video: optional predicate Cell -> bool selecting cells that also write
    overlay.mp4 (a done cell without its video is recomputed).
    """
    out = Path(out)
    if not paths:
        raise InputError("no recordings given")
    seen: dict[Path, str] = {}
    for p in paths:
        if not Path(p).exists():
            raise InputError(f"{p}: recording not found")
        if Path(p).resolve() in seen:
            raise InputError(f"{p}: the same recording as {seen[Path(p).resolve()]}, given twice")
        seen[Path(p).resolve()] = str(p)
    if workers < 1:
        raise InputError("--workers must be at least 1")
    if options.repeats < 1:
        raise InputError("--repeats must be at least 1")
    if ray_address is not None:
        check_ray_address(ray_address)   # before study.json: an unreachable cluster changes nothing
    cells, notes = plan([str(p) for p in paths], options, out, names)
    if not cells:
        raise InputError("no estimator/observation combination to run")
    refuse_other_runs(out, "study")
    check_study_folder(out, options, cells)
    if video is not None:
        for c in cells:
            c.video = bool(video(c))
    todo = [c for c in cells if not is_done(c) or (c.video and not (Path(c.out) / "overlay.mp4").is_file())]
    if ray_address is not None:
        run_ray(todo, ray_address, workers if workers > 1 else None, quiet) if todo else []
    else:
        run_local(todo, workers, quiet)
    plot_accumulated(out, cells)
    data = write_tables(out, cells, notes + recording_notes(cells))
    data["ran"] = len(todo)
    data["reused"] = len(cells) - len(todo)
    data["cells"] = cells
    return data
