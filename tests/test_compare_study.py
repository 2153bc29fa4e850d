"""graphtrack compare: tables, resume, refusing to mix options, failing cells, workers, Ray."""
import csv
import json
import shutil

import pytest

from graphtrack.cli import main

FRAMES = 16


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from graphtrack.sim.simulate import simulate

    return simulate(tmp_path_factory.mktemp("sim") / "rec", "structured", frames=FRAMES, seed=3,
                    size=(270, 480), progress=False, form="folder")


def _compare(rec_paths, out, *extra):
    return main(["compare", *map(str, rec_paths), "--out", str(out), "--quiet", "--max-frames", "12",
                 "--particles", "64", *extra])


@pytest.mark.slow
def test_compare_writes_table_csv_png_and_resumes(rec, tmp_path, capsys):
    out = tmp_path / "study"
    rc = _compare([rec], out, "--estimators", "kinematics,pf", "--observations", "line-intensities")
    assert rc == 0
    printed = capsys.readouterr().out   # --quiet drops the progress and the notes, never the table
    assert "line-intensities" in printed and "kinematics" in printed
    with (out / "table.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["observation", "estimator", "rec", "rec_std"]
    assert [r[:2] for r in rows[1:]] == [["—", "kinematics"], ["line-intensities", "pf"]]
    assert all(float(r[2]) >= 0 for r in rows[1:])
    md = (out / "table.md").read_text()
    assert "| line-intensities | pf |" in md and "| — | kinematics |" in md and "## Runtime" in md
    assert (out / "accumulated_error_rec.png").stat().st_size > 1000
    assert (out / "runtime.csv").is_file() and (out / "results.csv").is_file()
    cells = [out / "runs" / "rec" / "kinematics", out / "runs" / "rec" / "pf-line-intensities"]
    for c in cells:
        for name in ("trajectory.csv", "trajectory.tum", "metrics.json", "done.json"):
            assert (c / name).is_file(), c / name
    mtimes = {c: (c / "done.json").stat().st_mtime_ns for c in cells}

    # a second run reuses both cells
    assert _compare([rec], out, "--estimators", "kinematics,pf", "--observations", "line-intensities") == 0
    assert {c: (c / "done.json").stat().st_mtime_ns for c in cells} == mtimes

    # an interrupted study (one cell without done.json) recomputes only that cell
    (cells[1] / "done.json").unlink()
    from graphtrack.estimate.options import EstimatorOptions
    from graphtrack.study import StudyOptions, run_study

    data = run_study([str(rec)], out, StudyOptions(estimators=["kinematics", "pf"],
                                                   observations=["line-intensities"], max_frames=12,
                                                   estimation=EstimatorOptions(particles=64)), quiet=True)
    assert (data["ran"], data["reused"]) == (1, 1)
    assert (cells[0] / "done.json").stat().st_mtime_ns == mtimes[cells[0]]
    assert (cells[1] / "done.json").is_file()


def test_compare_refuses_mixing_options(rec, tmp_path, capsys):
    out = tmp_path / "study"
    assert _compare([rec], out, "--estimators", "kinematics") == 0
    capsys.readouterr()
    rc = main(["compare", str(rec), "--out", str(out), "--quiet", "--max-frames", "8",
               "--estimators", "kinematics"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "other options" in err and "max_frames" in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_failing_cell_is_reported_and_the_rest_completes(rec, tmp_path, capsys):
    bad = tmp_path / "broken"
    shutil.copytree(rec, bad)
    (bad / "robot.json").write_text("{ not json")
    out = tmp_path / "study"
    rc = _compare([rec, bad], out, "--estimators", "kinematics", "--workers", "2")
    assert rc == 2                    # the study is written, and its exit status says a cell failed
    assert (out / "runs" / "rec" / "kinematics" / "done.json").is_file()
    assert not (out / "runs" / "broken" / "kinematics" / "done.json").exists()
    assert json.loads((out / "runs" / "broken" / "kinematics" / "error.json").read_text())["error"]
    md = (out / "table.md").read_text()
    assert "## Errors" in md and "broken / kinematics" in md
    with (out / "table.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["observation", "estimator", "rec", "rec_std", "broken", "broken_std"]
    assert rows[1][4] == "error" and float(rows[1][2]) >= 0
    err = capsys.readouterr().err
    assert "broken/kinematics failed" in err and "graphtrack: error: 1 cell(s) failed" in err


def test_unknown_estimator_is_input_error(rec, tmp_path, capsys):
    assert _compare([rec], tmp_path / "s", "--estimators", "kinematics,nope") == 2
    assert "nope" in capsys.readouterr().err


@pytest.mark.slow
def test_compare_on_local_ray(rec, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "study"
    rc = _compare([rec], out, "--estimators", "kinematics", "--ray", "local", "--workers", "2")
    assert rc == 0
    cell = out / "runs" / "rec" / "kinematics"
    for name in ("trajectory.csv", "trajectory.tum", "metrics.json", "done.json"):
        assert (cell / name).is_file()
    assert json.loads((cell / "done.json").read_text())["result"]["frames_tracked"] == 12


@pytest.mark.slow
def test_repeats_run_seed_dependent_cells_and_report_their_mean(rec, tmp_path):
    out = tmp_path / "study"
    rc = _compare([rec], out, "--estimators", "pf,smoother", "--max-frames", "6",
                  "--observations", "line-intensities,line-intensities-polar", "--repeats", "2", "--seed", "3")
    assert rc == 0
    runs = out / "runs" / "rec"
    # the particle filter (resampling) and the RANSAC model depend on the seed; the
    # smoother on line-intensities does not and runs once
    assert sorted(p.name for p in runs.iterdir()) == [
        "pf-line-intensities", "pf-line-intensities-polar", "pf-line-intensities-polar.seed4",
        "pf-line-intensities.seed4", "smoother-line-intensities", "smoother-line-intensities-polar",
        "smoother-line-intensities-polar.seed4"]
    seeds = {p.name: json.loads((p / "done.json").read_text())["options"]["seed"] for p in runs.iterdir()}
    assert seeds["pf-line-intensities"] == 3 and seeds["pf-line-intensities.seed4"] == 4

    def mean_pct(folder):
        return json.loads((runs / folder / "metrics.json").read_text())["tip_error_percent_diagonal"]["mean"]

    with (out / "table.csv").open() as f:
        table = {(r[0], r[1]): float(r[2]) for r in list(csv.reader(f))[1:]}
    want = (mean_pct("pf-line-intensities") + mean_pct("pf-line-intensities.seed4")) / 2
    assert table["line-intensities", "pf"] == pytest.approx(want, abs=1e-4)
    assert table["line-intensities", "smoother"] == pytest.approx(mean_pct("smoother-line-intensities"), abs=1e-4)
    with (out / "results.csv").open() as f:
        res = list(csv.DictReader(f))
    assert len(res) == 7
    assert sorted(r["seed"] for r in res if r["estimator"] == "pf" and r["observation"] == "line-intensities") \
        == ["3", "4"]
    assert "(2 seeds)" in (out / "table.md").read_text()
    assert _compare([rec], out, "--estimators", "pf", "--repeats", "0") == 2


def test_the_plot_names_its_seed(rec, tmp_path, monkeypatch):
    """The accumulated-error plot draws a repeated cell's first seed (table.csv: their mean),
    and says so (its curves are labelled by the cells' rows, "(mono)" included:
    test_track_stereo.py)."""
    from matplotlib.figure import Figure

    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, path, **kw: seen.append(
        (fig.axes[0].get_title(), [t.get_text() for t in fig.axes[0].get_legend().get_texts()])))
    out = tmp_path / "study"
    assert _compare([rec], out, "--estimators", "pf", "--observations", "line-intensities", "--max-frames", "4",
                    "--repeats", "2", "--seed", "3") == 0
    title, legend = seen[-1]
    assert "the run with seed 3" in title and legend == ["pf / line-intensities"]


def test_every_curve_of_the_plot_can_be_told_apart(rec, tmp_path, monkeypatch):
    """Four estimators x two observation models: no two curves share colour and line style
    (matplotlib's default cycle repeats after 10)."""
    from matplotlib.figure import Figure

    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, path, **kw: seen.append(
        ([(tuple(ln.get_color()), str(ln.get_linestyle())) for ln in fig.axes[0].get_lines()],
         fig.axes[0].get_yscale())))
    out = tmp_path / "study"
    assert _compare([rec], out, "--estimators", "kinematics,pf,smoother,batch", "--observations",
                    "line-intensities,line-intensities-polar", "--max-frames", "6", "--particles", "64") == 0
    styles, _ = seen[-1]
    assert len(styles) == 7 and len(set(styles)) == 7


def test_a_recording_without_labels_is_named_in_the_notes(rec, tmp_path):
    """Without labels.csv every accuracy entry is n/a: table.md says why instead of
    leaving a table of n/a and no plot unexplained."""
    bare = tmp_path / "bare"
    shutil.copytree(rec, bare)
    (bare / "labels.csv").unlink()
    out = tmp_path / "study"
    assert _compare([rec, bare], out, "--estimators", "kinematics", "--observations", "line-intensities") == 0
    md = (out / "table.md").read_text()
    assert "- no labels.csv in bare: the tip error there is n/a" in md
    assert "in rec" not in md.split("## Notes")[1]
    assert (out / "accumulated_error_rec.png").is_file() and not (out / "accumulated_error_bare.png").exists()
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["frames_tracked"] for r in rows} == {"12"} and {r["frames_skipped"] for r in rows} == {"0"}


def test_recording_names_are_unique_past_every_folder_name():
    """a/rec b/rec c/rec_2: b's clash is not numbered into c's name (that dropped a
    recording from the study with exit 0)."""
    from graphtrack.study.plan import recording_names

    assert recording_names(["/p1/rec", "/p2/rec", "/p3/rec_2"]) == ["rec", "rec_3", "rec_2"]
    assert recording_names(["/p3/rec_2", "/p1/rec", "/p2/rec"]) == ["rec_2", "rec", "rec_3"]
    assert recording_names(["/a/x", "/b/x", "/c/x"]) == ["x", "x_2", "x_3"]


def test_a_missing_weights_file_is_refused_before_the_study(rec, tmp_path, capsys):
    """It failed every cell after the fact, and its study.json then refused the corrected command."""
    out = tmp_path / "study"
    assert _compare([rec], out, "--weights", str(tmp_path / "none.pt")) == 2
    assert f"--weights {tmp_path / 'none.pt'}: weights file not found" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.parametrize("how", ["sigint_group", "sigterm_parent"])
def test_stopping_a_parallel_study_leaves_no_workers_and_no_false_failures(rec, tmp_path, how):
    """Ctrl-C (SIGINT to the whole process group) or kill (SIGTERM to the parent) during
    `compare --workers 2`: exit 130, no worker left running (they were orphaned at 390 MB
    each), and no cell marked failed by the interrupt (workers broke mid-import)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "study"
    p = subprocess.Popen([sys.executable, "-m", "graphtrack.cli", "compare", str(rec), "--out", str(out),
                          "--estimators", "kinematics,pf,smoother", "--observations", "canny,line-intensities",
                          "--workers", "2", "--max-frames", "12", "--particles", "64", "--repeats", "4", "--quiet"],
                         start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    t0 = time.monotonic()   # stopped once a cell is done: the workers are running others, most are left
    while not list(out.glob("runs/*/*/done.json")) and p.poll() is None and time.monotonic() - t0 < 120:
        time.sleep(0.1)
    if how == "sigint_group":
        os.killpg(p.pid, signal.SIGINT)
    else:
        p.send_signal(signal.SIGTERM)
    std, err = p.communicate(timeout=60)
    assert "kinematics" not in std, "the study finished before it was stopped: the test did not test"
    assert p.returncode == 130 and "interrupted" in err and "Traceback" not in err, (p.returncode, err)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30:                      # every process of the session has ended
        try:
            os.killpg(p.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        pytest.fail("study workers still running after the study was stopped")
    failed = [json.loads(e.read_text()) for e in out.glob("runs/*/*/error.json")]
    assert not any(f.get("internal") for f in failed), failed
