"""The hand-eye prior's region and a run's correction (graphtrack.estimate.prior_region), and
the tracker's warnings when a run's correction lies beyond the prior or its estimate explained
almost none of its frames."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphtrack.estimate.prior_region import PRIOR_HINT, correction, prior_distance


def _perturbed(E0, b, w):
    """[R(w) b; 0 1] . E0, R from scipy's rotation vector (the oracle)."""
    D = np.eye(4)
    D[:3, :3], D[:3, 3] = Rotation.from_rotvec(w).as_matrix(), b
    return D @ E0


def test_correction_is_the_median_perturbation():
    rng = np.random.default_rng(3)
    E0 = _perturbed(np.eye(4), rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.3)
    sizes = [(0.010, 2.0), (0.020, 4.0), (0.030, 8.0)]            # |b| m, |w| deg per frame
    Es, d = [], []
    for nb, nw in sizes:
        ub, uw = rng.normal(size=3), rng.normal(size=3)
        b, w = nb * ub / np.linalg.norm(ub), math.radians(nw) * uw / np.linalg.norm(uw)
        Es.append(_perturbed(E0, b, w))
        d.append(np.sum((b / 0.005) ** 2) + np.sum((w / 0.035) ** 2))
    c = correction(Es, E0, 0.005, 0.035)
    assert c["frames"] == 3
    assert c["b_mm"] == pytest.approx(20.0, abs=1e-6) and c["w_deg"] == pytest.approx(4.0, abs=1e-6)
    assert c["prior_distance"] == pytest.approx(np.median(d), rel=1e-6)
    assert prior_distance(Es[0], E0, 0.005, 0.035) == pytest.approx(d[0], rel=1e-6)
    assert correction([], E0, 0.005, 0.035) == {}


def _tracked(tmp_path, capsys, frames: int, seed: int, size: tuple) -> dict:
    """metrics.json of the default track of a simulated structured recording whose
    handeye.yaml is off by size = (m, deg)."""
    from graphtrack.cli import main
    from graphtrack.sim.simulate import simulate

    rec = simulate(tmp_path / "rec", "structured", frames=frames, seed=seed, size=(270, 480), form="folder",
                   progress=False, handeye_error=(size[0], math.radians(size[1])))
    capsys.readouterr()
    assert main(["track", str(rec), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    return json.loads((tmp_path / "run" / "metrics.json").read_text())


@pytest.mark.parametrize("size,warned", [((0.025, 10.0), True), ((0.002, 1.0), False)])
def test_a_run_far_from_its_calibration_names_handeye_sigma(size, warned, tmp_path, capsys):
    """A recording whose handeye.yaml is 25 mm / 10 deg off: the smoother's correction lies
    beyond the prior's 99 % region, metrics.json says so and the run warns, naming
    --handeye-sigma; 2 mm / 1 deg off: no warning."""
    m = _tracked(tmp_path, capsys, 10, 8, size)
    c = m["handeye_correction"]
    assert c["frames"] > 0 and (c["prior_distance"] > PRIOR_HINT) is warned
    assert any("--handeye-sigma" in line for line in m["recording_warnings"]) is warned


@pytest.mark.parametrize("size,warned", [((0.040, 15.0), True), ((0.002, 1.0), False)])
def test_a_run_that_never_reached_the_tool_says_so(size, warned, tmp_path, capsys):
    """A recording whose handeye.yaml is 40 mm / 15 deg off (seed 3): the prediction lies
    beyond the search's reach, no mode is adopted and the estimate stays at the calibration
    (its correction 0, no prior-distance hint), explaining none of the frames it judges;
    metrics.json counts them and the run warns, naming --handeye-sigma. 2 mm / 1 deg off:
    every frame after the start-up is judged and explained, no such warning."""
    m = _tracked(tmp_path, capsys, 14, 3, size)
    r = m["estimator_report"]
    assert r["frames_judged"] == m["frames_with_detections"] - 1 == 13   # the start-up's frame is searched
    assert (r["frames_explained"] < 0.15 * r["frames_judged"]) is warned
    assert (r["frames_explained"] == r["frames_judged"]) is not warned
    unexplained = [line for line in m["recording_warnings"] if "the estimate explained the detections" in line]
    assert len(unexplained) == int(warned)
    assert all("--handeye-sigma" in line for line in unexplained)
