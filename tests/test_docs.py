"""The user documentation is true to the code and self-contained.

- README.md: at most 200 lines, opening with exactly two commands (set up and run
  the demo; set up and run the tests), quoting no benchmark figure;
- README.md, docs/ and the package's docstrings refer to nothing outside the
  repository, and every relative link resolves;
- every option a documented ``graphtrack`` command line uses exists on that command;
- docs/sequence-format.md names every file, column and key graphtrack reads and writes,
  checked against what the code actually writes (a simulated stereo recording, tracked).
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import re
from pathlib import Path

import pytest

from graphtrack.cli import build_parser
from graphtrack.io.topics import ARMS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FORMAT = ROOT / "docs" / "sequence-format.md"
DOCS = [README, *sorted((ROOT / "docs").rglob("*.md"))]


def test_readme_is_short_and_opens_with_the_two_commands():
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    first = re.search(r"```(?:bash|sh)?\n(.*?)```", text, re.S)
    assert first and text.index(first.group(0)) < text.index("\n## ")   # before any section
    commands = [c for c in first.group(1).splitlines() if c.strip()]
    assert len(commands) == 2, commands
    demo, tests = commands
    assert demo.startswith("pip install") and demo.rstrip().endswith("graphtrack demo")
    assert tests.startswith("pip install") and "pytest" in tests and "[test" in tests


def test_readme_quotes_no_benchmark_figures_and_links_results():
    text = README.read_text()
    figures = re.findall(r"\d+(?:\.\d+)?\s*(?:frames/s|fps\b|ms\b|%)", text)
    assert not figures, figures
    assert "benchmarks/RESULTS.md" in text and (ROOT / "benchmarks" / "RESULTS.md").is_file()


def test_nothing_refers_outside_the_repository():
    texts = {p: p.read_text() for p in DOCS}
    texts.update({p: p.read_text() for p in (ROOT / "graphtrack").rglob("*.py")})
    for path, text in texts.items():
        for bad in ("../shared", "shared/docs", "/work/"):
            assert bad not in text, f"{path.relative_to(ROOT)} refers to {bad!r}"
    for path in DOCS:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", path.read_text()):
            if re.match(r"[a-z]+://", target):
                continue
            resolved = (path.parent / target).resolve()
            assert resolved.exists() and ROOT in resolved.parents, f"{path.relative_to(ROOT)}: {target}"


def _options() -> dict[str, set[str]]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {name: {s for a in p._actions for s in a.option_strings} for name, p in sub.choices.items()}


def test_documented_command_lines_use_existing_options():
    options = _options()
    checked = 0
    for path in DOCS:
        # join continuation lines, then read every "graphtrack COMMAND ..." up to the end of its line
        text = path.read_text().replace("\\\n", " ")
        for command, rest in re.findall(r"graphtrack (\w+)((?:[^\n`|]|\\\|)*)", text):
            if command not in options:
                continue
            for flag in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", rest):
                assert flag in options[command], f"{path.relative_to(ROOT)}: graphtrack {command} {flag}"
                checked += 1
    assert checked > 20
    readme = README.read_text()
    for command in ("demo", "track", "refine", "compare", "robot", "simulate"):
        assert f"graphtrack {command}" in readme


def test_format_doc_names_the_inputs():
    doc = FORMAT.read_text()
    from graphtrack.robot.psm import psm_large_needle_driver

    robot = psm_large_needle_driver().to_json()
    keys = set(robot)
    for key in ("DH_params", "point_features", "shaft_features", "skeleton_structure"):
        keys |= {f"{key}[i].{k}" for entry in robot[key] for k in entry if key != "skeleton_structure"}
    for key in sorted(keys):
        name = key.rsplit(".", 1)[-1]
        assert f"`{key}`" in doc or f"`.{name}`" in doc or f".{name}`" in doc, f"robot.json key {key}"
    for key in ("ImageSize", "K1", "D1", "K2", "D2", "R", "T"):
        assert f"`{key}`" in doc, key
    for arm in ARMS:
        assert f"`{arm}_`" in doc                                   # handeye.yaml key prefixes
    for topic in ("/stereo/left/image", "/stereo/left/image/compressed", "/stereo/right/image",
                  "/dvrk/PSM1/state_joint_current", "/dvrk/PSM1/state_jaw_current",
                  "/PSM1/measured_js", "/PSM1/jaw/measured_js"):
        assert f"`{topic}`" in doc, topic
    for opt in ("--arm", "--image-topic", "--joint-topic", "--jaw-topic"):
        assert f"`{opt}`" in doc, opt
    assert "graphtrack robot psm.json LARGE_NEEDLE_DRIVER_400006.json" in doc
    for name in ("frames/", "joints.csv", "frames_right/", "labels.csv", "labels_right.csv", "truth.csv",
                 "video.mp4"):
        assert f"`{name}`" in doc, name


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """A stereo simulated recording tracked by the smoother: the files graphtrack really writes."""
    from graphtrack.cli import main
    from graphtrack.sim.simulate import simulate

    root = tmp_path_factory.mktemp("docs")
    seq = simulate(root / "seq", "tissue", frames=6, seed=4, size=(270, 480), progress=False,
                   form="folder", stereo=True)
    out = root / "run"
    assert main(["track", str(seq), "--out", str(out), "--detector", "canny", "--video", "--quiet"]) == 0
    det = root / "det"
    assert main(["detect", str(seq), "--out", str(det), "--detector", "canny", "--quiet"]) == 0
    return seq, out, det


def _header(path: Path) -> list[str]:
    with path.open() as f:
        return next(csv.reader(f))


def test_format_doc_names_every_output_file_column_and_key(tracked):
    seq, out, det = tracked
    doc = FORMAT.read_text()

    def named(x: str) -> bool:   # the name as a whole word: `x`, `a, x`, `x_i` rows of a table
        return re.search(rf"(?<![\w.]){re.escape(x)}(?![\w])", doc) is not None

    for f in sorted(p.name for p in out.iterdir()) + sorted(p.name for p in det.iterdir()):
        assert f"`{f}`" in doc or f"**`{f}`**" in doc, f"output file {f}"
    for column in _header(out / "trajectory.csv") + _header(out / "truth_errors.csv"):
        assert named(column), f"trajectory column {column}"
    for column in _header(det / "detections.csv"):
        generic = re.sub(r"_\d$", "_i", column)
        assert named(column) or generic in doc, f"detections.csv column {column}"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["stereo"] is True and "nees" in metrics
    for key in metrics:
        assert named(key), f"metrics.json key {key}"
    for f in ("trajectory.tum", "overlay.mp4", "detections_right.csv", "scenario.json", "study.json",
              "table.md", "table.csv", "runtime.csv", "results.csv", "done.json", "error.json"):
        assert f in doc, f


def test_readme_python_snippet_runs(tmp_path, monkeypatch):
    from graphtrack.sim.simulate import simulate

    simulate(tmp_path / "SEQ", "structured", frames=5, seed=1, size=(270, 480), progress=False, form="folder")
    monkeypatch.chdir(tmp_path)
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    code = code.replace('TrackOptions(estimator="smoother")', 'TrackOptions(estimator="smoother"), quiet=True, '
                                                              'progress=False')
    scope: dict = {}
    with _threads_restored(monkeypatch):    # the snippet's limit_threads(1) stays inside it
        exec(compile(code, "README.md", "exec"), scope)
    assert scope["E"].shape == (4, 4) and scope["metrics"]["frames_tracked"] == 5
    assert (tmp_path / "out" / "trajectory.csv").is_file()


@contextlib.contextmanager
def _threads_restored(monkeypatch):
    """Run a block that calls limit_threads, then give torch, OpenCV, BLAS and the
    environment back the thread counts they had (the rest of the suite keeps its own)."""
    import cv2
    import torch
    from threadpoolctl import threadpool_info, threadpool_limits

    from graphtrack.threads import THREAD_ENV

    for var in THREAD_ENV:
        if var in os.environ:
            monkeypatch.setenv(var, os.environ[var])
        else:
            monkeypatch.delenv(var, raising=False)
    before = (torch.get_num_threads(), cv2.getNumThreads(), threadpool_info())
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        cv2.setNumThreads(before[1])
        threadpool_limits({lib["prefix"]: lib["num_threads"] for lib in before[2]})
