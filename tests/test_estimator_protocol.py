"""Every registered estimator declares the whole Estimator protocol on its own class, with
values the tracking loop and the studies rely on (nothing is probed with getattr)."""
from __future__ import annotations

import pytest

from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.estimate import ESTIMATORS, estimator_class
from graphtrack.estimate.base import STD_COLUMNS, Estimator
from graphtrack.study.plan import plan, seed_dependent
from graphtrack.study.cells import StudyOptions

MEMBERS = ("name", "uses_observations", "stochastic", "supported_observations", "extra_columns", "step", "finish",
           "report")


def test_protocol_lists_what_the_loop_uses():
    declared = set(Estimator.__annotations__) | {n for n in vars(Estimator) if not n.startswith("_")}
    assert set(MEMBERS) <= declared


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_every_estimator_declares_the_protocol(name):
    cls = estimator_class(name)
    for m in MEMBERS:
        assert any(m in vars(k) for k in cls.__mro__ if k is not object), f"{name} lacks {m}"
    assert cls.name == name
    assert isinstance(cls.uses_observations, bool) and isinstance(cls.stochastic, bool)
    assert set(cls.supported_observations) <= set(OBSERVATION_MODELS)
    # an estimator that reads observations scores some; one that does not, none
    assert bool(cls.supported_observations) == cls.uses_observations
    assert all(isinstance(c, str) for c in cls.extra_columns)


def test_the_declared_values():
    """Independent facts: the PF resamples at random; the kinematics baseline uses no images;
    the filter, smoother and batch score all six models and report their standard deviations."""
    assert estimator_class("pf").stochastic
    assert not any(estimator_class(n).stochastic for n in ("kinematics", "smoother", "batch"))
    assert not estimator_class("kinematics").uses_observations
    for n in ("pf", "smoother", "batch"):
        assert tuple(estimator_class(n).supported_observations) == tuple(OBSERVATION_MODELS)
        assert set(STD_COLUMNS) <= set(estimator_class(n).extra_columns)


def test_study_plans_from_the_declared_attributes(tmp_path):
    """One cell per recording for the estimator without observations, every model for the others;
    repeats only for the seed-dependent cells (the PF, the RANSAC models)."""
    assert seed_dependent("pf", "line-intensities")
    assert seed_dependent("smoother", "line-intensities-polar")
    assert not seed_dependent("smoother", "line-intensities")
    assert not seed_dependent("kinematics", None)
    opts = StudyOptions(estimators=["kinematics", "smoother"], observations=["canny", "line-intensities-polar"],
                        repeats=2)
    cells, notes = plan([str(tmp_path)], opts, tmp_path / "study", names=["r"])
    assert [c.key for c in cells] == ["kinematics", "smoother-canny", "smoother-line-intensities-polar",
                                      "smoother-line-intensities-polar.seed1"]
    assert notes == []
