"""The command line's options: defaults shown by --help are the options dataclasses' own,
``track`` runs the smoother by default, ``refine`` offers no filter/smoother options."""
from __future__ import annotations

import argparse

import pytest

from graphtrack.cli import build_parser
from graphtrack.commands.compare import study_options_from_args
from graphtrack.commands.track import options_from_args
from graphtrack.detect.options import DetectionOptions
from graphtrack.errors import InputError
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.study import StudyOptions
from graphtrack.track import TrackOptions


def _subparsers():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def _help_lines(parser) -> dict[str, str]:
    """{option string: its entry in the rendered --help, continuation lines joined} (COLUMNS is
    wide, so the help text is never wrapped, only moved below a long invocation)."""
    lines, flags = {}, []
    for line in parser.format_help().splitlines():
        if line.startswith("  -"):
            flags = [f for f in line.split("  ")[1].replace(",", " ").split() if f.startswith("-")]
            for flag in flags:
                lines[flag] = line
        elif line.startswith("    ") and flags:
            for flag in flags:
                lines[flag] += " " + line.strip()
        else:
            flags = []
    return lines


def test_every_option_help_shows_its_default(monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")
    checked = 0
    for name, p in _subparsers().items():
        lines = _help_lines(p)
        for a in p._actions:
            if not a.option_strings or a.help == argparse.SUPPRESS or isinstance(a, argparse._HelpAction):
                continue
            line = lines[a.option_strings[0]]
            where = f"graphtrack {name} {a.option_strings[0]}: {line.strip()!r}"
            assert a.help and len(a.help.split()) >= 2, where                  # every option says what it does
            if a.required:
                assert "default" not in line, where
                continue
            assert line.count("(default: ") == 1, where
            shown = line.split("(default: ", 1)[1]
            assert not shown.startswith(("None", "False", "True")), where   # say what happens instead
            if "default:" in (a.help or ""):
                continue                                   # the help's own words, e.g. "default: all"
            if isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
                assert shown.startswith("off)"), where
            elif a.default is not None and "%(default)" not in (a.help or ""):
                assert shown.startswith(f"{a.default})"), where
            checked += 1
    assert checked > 60
    text = _subparsers()["track"].format_help()
    assert f"(default: {DetectionOptions.alpha})" in text and "(default: smoother)" in text
    assert f"(default: {EstimatorOptions.particles})" in text and "(default: learned)" in text
    assert "(default: 540x960)" in _subparsers()["simulate"].format_help()


def test_track_runs_the_smoother_unless_told_otherwise():
    args = build_parser().parse_args(["track", "SEQ", "--out", "O"])
    assert options_from_args(args) == TrackOptions()
    assert TrackOptions().estimator == "smoother"
    args = build_parser().parse_args(["track", "SEQ", "--out", "O", "--estimator", "pf", "--seed", "4",
                                      "--particles", "50", "--alpha", "7", "--no-markers"])
    o = options_from_args(args)
    assert (o.estimator, o.seed, o.estimation.seed, o.estimation.particles) == ("pf", 4, 4, 50)
    assert (o.detection.alpha, o.detection.markers) == (7.0, False)


def test_refine_offers_no_particles():
    refine = _subparsers()["refine"]
    flags = {s for a in refine._actions for s in a.option_strings}
    assert "--particles" not in flags and "--lag" not in flags
    with pytest.raises(SystemExit):
        build_parser().parse_args(["refine", "SEQ", "--out", "O", "--particles", "5"])


def test_compare_builds_the_same_defaults_as_the_library():
    args = build_parser().parse_args(["compare", "SEQ", "--out", "O"])
    o = study_options_from_args(args)
    d = StudyOptions()
    assert (o.detection, o.estimation, o.seed, o.estimators) == (d.detection, d.estimation, d.seed, d.estimators)


@pytest.mark.parametrize("extra,what", [(["--particles", "0"], "--particles"), (["--lag", "-1"], "--lag"),
                                        (["--detect-scale", "2"], "--detect-scale")])
def test_bad_values_name_the_option(extra, what):
    args = build_parser().parse_args(["track", "SEQ", "--out", "O", *extra])
    with pytest.raises(InputError, match=what):
        options_from_args(args)


def test_no_search_flag():
    args = build_parser().parse_args(["track", "SEQ", "--out", "O", "--no-search"])
    assert options_from_args(args).estimation.search is False
    args = build_parser().parse_args(["track", "SEQ", "--out", "O"])
    assert options_from_args(args).estimation.search is EstimatorOptions.search is True


def test_estimator_keywords():
    assert EstimatorOptions(particles=7, seed=2).keywords("pf") == {"particles": 7, "seed": 2, "search": True}
    assert EstimatorOptions(lag=2.0).keywords("smoother") == {"lag": 2.0, "smoother": "isam2", "search": True}
    assert EstimatorOptions(search=False).keywords("pf")["search"] is False
    assert EstimatorOptions(search=False).keywords("pf")["window_move"] is False   # the filter of before
    assert "window_move" not in EstimatorOptions(search=False).keywords("smoother")
    assert EstimatorOptions(edge_bias=False).keywords("batch") == {"edge_bias": False}
    assert EstimatorOptions().keywords("kinematics") == {}


def test_handeye_sigma_sets_the_prior_and_scales_the_search():
    """--handeye-sigma 12,5 (mm, deg): the smoother's and batch's prior is (12 mm, 5 deg) per
    axis, the search's spread and the particle filter's initial cloud grow by 12/5 and
    5 deg / PRIOR_SIGMA_W; compare hands it to every cell."""
    import math

    from graphtrack.estimate import options as eo

    args = build_parser().parse_args(["track", "SEQ", "--out", "O", "--handeye-sigma", "12,5"])
    e = options_from_args(args).estimation
    b, w = 0.012, math.radians(5.0)
    assert e.handeye_sigma == pytest.approx((b, w)) and e.prior_sigma == pytest.approx((b, w))
    fb, fw = b / eo.PRIOR_SIGMA_B, w / eo.PRIOR_SIGMA_W
    smoother = e.keywords("smoother")
    assert (smoother["prior_sigma_b"], smoother["prior_sigma_w"]) == pytest.approx((b, w))
    assert (smoother["search_std_b"], smoother["search_std_w"]) == pytest.approx((eo.SEARCH_STD_B * fb,
                                                                                  eo.SEARCH_STD_W * fw))
    pf = e.keywords("pf")
    assert "prior_sigma_b" not in pf
    assert (pf["init_std_b"], pf["init_std_w"]) == pytest.approx((eo.INIT_STD_B * fb, eo.INIT_STD_W * fw))
    assert e.keywords("batch")["prior_sigma_b"] == pytest.approx(b) and e.keywords("kinematics") == {}
    assert EstimatorOptions().prior_sigma == (eo.PRIOR_SIGMA_B, eo.PRIOR_SIGMA_W)

    cargs = build_parser().parse_args(["compare", "SEQ", "--out", "O", "--handeye-sigma", "12,5"])
    study = study_options_from_args(cargs)
    assert study.estimation.handeye_sigma == pytest.approx((b, w))
    from graphtrack.study.cells import Cell
    cell = Cell("r", "r", "smoother", "line-intensities", "o", study.cell_options())
    assert cell.track_options().estimation.handeye_sigma == pytest.approx((b, w))


@pytest.mark.parametrize("value", ["12", "a,b", "0,5", "12,-1", "nan,5", "500,5", "12,5,1"])
def test_bad_handeye_sigma_names_the_option(value):
    args = build_parser().parse_args(["track", "SEQ", "--out", "O", "--handeye-sigma", value])
    with pytest.raises(InputError, match="--handeye-sigma"):
        options_from_args(args)


def test_handeye_sigma_is_said_to_be_ignored_by_kinematics():
    from graphtrack.commands.track import unused_options

    args = build_parser().parse_args(["track", "SEQ", "--out", "O", "--estimator", "kinematics",
                                      "--handeye-sigma", "12,5"])
    assert any("--handeye-sigma" in line for line in unused_options(args))
    args = build_parser().parse_args(["track", "SEQ", "--out", "O", "--handeye-sigma", "12,5"])
    assert unused_options(args) == []


@pytest.mark.parametrize("argv, turn", [([], True), (["--no-turn"], False)])
def test_compare_no_turn_reaches_every_cell(argv, turn):
    """compare --no-turn is a study option: each cell's detector keeps its input unturned,
    and a study written before the option existed reads as turned."""
    from graphtrack.study.cells import CELL_OPTION_DEFAULTS, Cell

    study = study_options_from_args(build_parser().parse_args(["compare", "SEQ", "--out", "O", *argv]))
    assert study.cell_options()["turn"] is turn
    cell = Cell("r", "r", "smoother", "line-intensities", "o", study.cell_options())
    assert cell.track_options().detection.turn is turn
    assert CELL_OPTION_DEFAULTS["turn"] is True
    canny = study_options_from_args(build_parser().parse_args(["compare", "SEQ", "--out", "O", "--detector",
                                                               "canny", *argv]))
    assert canny.cell_options()["turn"] is True   # only the learned net turns: a canny study is the same
