"""The study's report tables (graphtrack.study.report) from a hand-made results set."""
import csv
import json

import pytest

from graphtrack.study.cells import Cell
from graphtrack.study.report import cell_status, format_table, is_done, write_tables


def make_cell(root, rec, est, obs, seed=0, repeat=0, result=None, error=None):
    """A cell folder: done.json + metrics.json for a result, error.json for an error, nothing else."""
    name = est if obs is None else f"{est}-{obs}"
    out = root / "runs" / rec / (name if repeat == 0 else f"{name}.seed{seed}")
    out.mkdir(parents=True)
    opts = {"seed": seed}
    if result is not None:
        (out / "metrics.json").write_text(json.dumps(result))
        (out / "done.json").write_text(json.dumps({"options": opts, "result": result}))
    if error is not None:
        (out / "error.json").write_text(json.dumps({"error": error}))
    return Cell(rec, str(root / rec), est, obs, str(out), opts, repeat=repeat)


def res(mean, std, ms, fps, steady=True):
    """A run's metrics: ``ms`` the median of trajectory.csv's ms, ``fps`` the steady rate (1000 / the
    steady mean ms, as track writes it); the wall-clock fps counts the start-up: never the table's."""
    r = {"tip_error_percent_diagonal": {"mean": mean, "std": std}, "runtime_ms": {"median": ms}, "fps_steady": fps,
         "fps": fps / 2}
    if steady:
        r["frame_ms_mean"] = 1e3 / fps
    return r


@pytest.fixture
def study(tmp_path):
    cells = [
        make_cell(tmp_path, "A", "kinematics", None, result=res(5.0, 1.0, 0.1, 1000.0)),
        make_cell(tmp_path, "B", "kinematics", None, result=res(7.0, 2.0, 0.2, 900.0, steady=False)),  # an older run
        # a stochastic estimator with 2 seeds on A: the entry is the mean of the two runs
        make_cell(tmp_path, "A", "pf", "canny", seed=0, result=res(2.0, 0.5, 10.0, 50.0)),
        make_cell(tmp_path, "A", "pf", "canny", seed=1, repeat=1, result=res(3.0, 1.5, 12.0, 40.0)),
        make_cell(tmp_path, "B", "pf", "canny", error="boom: detector crashed"),
        make_cell(tmp_path, "A", "smoother", "canny"),                       # not run yet
        make_cell(tmp_path, "B", "smoother", "canny", result=res(float("nan"), None, 20.0, 30.0)),
    ]
    return tmp_path, cells


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.reader(f))


def test_cell_states(study):
    root, cells = study
    assert [cell_status(c)["state"] for c in cells] == ["done", "done", "done", "done", "error", "missing", "done"]
    assert cell_status(cells[4])["error"] == "boom: detector crashed"
    # done.json written for other options is not this cell's result
    stale = Cell("A", "", "kinematics", None, cells[0].out, {"seed": 99})
    assert not is_done(stale) and cell_status(stale)["state"] == "missing"


def test_tables_by_hand(study):
    root, cells = study
    data = write_tables(root, cells, ["a note"])
    assert data["recordings"] == ["A", "B"]
    assert data["rows"] == [("—", "kinematics"), ("canny", "pf"), ("canny", "smoother")]
    acc, run = data["accuracy"], data["runtime"]
    assert acc[("—", "kinematics"), "A"] == (5.0, 1.0) and acc[("—", "kinematics"), "B"] == (7.0, 2.0)
    assert acc[("canny", "pf"), "A"] == pytest.approx((2.5, 1.0))             # means over the 2 seeds
    assert run[("canny", "pf"), "A"] == pytest.approx((22.5, 1e3 / 22.5))      # mean ms of 20 and 25, 1000 / it
    assert run[("—", "kinematics"), "B"] == pytest.approx((0.2, 5000.0))       # without frame_ms_mean: the median
    for v in run.values():
        if not isinstance(v, str) and v[0] == v[0]:
            assert v[0] * v[1] == pytest.approx(1e3)                         # the two numbers always agree
    assert data["spread"] == {(("canny", "pf"), "A"): (2.0, 3.0, 2)}
    assert acc[("canny", "pf"), "B"] == "error" and acc[("canny", "smoother"), "A"] == "missing"
    assert data["errors"] == [("B", "pf-canny", "boom: detector crashed")]

    md = (root / "table.md").read_text()
    assert "| — | kinematics | 5.00 (1.00) | 7.00 (2.00) |" in md
    assert "| canny | pf | 2.50 (1.00) | error |" in md
    assert "| canny | smoother | missing | n/a (n/a) |" in md         # NaN / None print as n/a
    assert "| canny | pf | 2.00 - 3.00 (2 seeds) | 1 seed |" in md
    assert "| canny | pf | 22.5 (44.4) | error |" in md
    assert "- a note" in md and "- B / pf-canny: boom: detector crashed" in md

    t = read_csv(root / "table.csv")
    assert t[0] == ["observation", "estimator", "A", "A_std", "B", "B_std"]
    assert t[1] == ["—", "kinematics", "5.0000", "1.0000", "7.0000", "2.0000"]
    assert t[2] == ["canny", "pf", "2.5000", "1.0000", "error", ""]
    r = read_csv(root / "runtime.csv")
    assert r[0] == ["observation", "estimator", "A_ms_mean", "A_fps", "B_ms_mean", "B_fps"]
    assert r[3] == ["canny", "smoother", "missing", "", "33.333", "30.000"]

    rows = read_csv(root / "results.csv")
    head = rows[0]
    assert head[:5] == ["recording", "observation", "estimator", "seed", "state"] and head[-1] == "error"
    assert len(rows) == 1 + len(cells)
    by = {(x[0], x[2], x[3]): dict(zip(head, x)) for x in rows[1:]}
    assert by["A", "pf", "1"]["tip_error_percent_diagonal.mean"] == "3.0000"
    assert by["A", "pf", "1"]["fps"] == "20.0000" and by["A", "pf", "1"]["fps_steady"] == "40.0000"
    assert by["A", "pf", "1"]["tip_error_px.mean"] == "n/a"                 # not in the result
    assert by["B", "pf", "0"]["state"] == "error" and by["B", "pf", "0"]["error"] == "boom: detector crashed"


def test_format_table_aligned(study):
    root, cells = study
    text = format_table(write_tables(root, cells, []))
    lines = text.splitlines()
    assert lines[0].split() == ["observation", "estimator", "A", "B"]
    assert set(lines[1].replace(" ", "")) == {"-"}
    assert lines[3].split() == ["canny", "pf", "2.50", "(1.00)", "error"]
    starts = {ln.index(ln.split()[2]) for ln in (lines[0], lines[2])}
    assert len(starts) == 1                                                    # the columns line up
