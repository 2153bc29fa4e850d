"""``graphtrack train`` with a tiny config, and the ground-truth labels it trains on."""
from __future__ import annotations

import numpy as np
import pytest
import torch


def test_labels_lie_on_true_limb_lines():
    from graphtrack.geometry.lines import line_difference, line_through
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation
    from graphtrack.training.labels import shaft_edge_segments

    sim = Simulation("tissue", 5, seed=11, size=(270, 480))
    cam = sim.camera
    seg = shaft_edge_segments(sim.robot, sim.q_read[2], sim.E_t[2], cam.K, cam.height, cam.width)
    assert len(seg) == 2
    rho, th, _ = shaft_lines(base_features(sim.robot, sim.q_read[2]).transformed(sim.E_t[2]), cam.K)
    r, t = line_through(seg[:, :2], seg[:, 2:])
    for i in range(2):
        dr, dt = line_difference(r[i], t[i], rho, th)
        assert np.min(np.abs(dr) + np.abs(dt)) < 1e-6
    assert np.all(seg[:, 0::2] >= -0.5 - 1e-9) and np.all(seg[:, 0::2] <= cam.width - 0.5 + 1e-9)


def test_target_maps():
    from graphtrack.training.labels import target_maps

    seg = np.full((1, 2, 4), np.nan, np.float32)
    seg[0, 0] = [5, 5, 30, 5]
    y = target_maps(seg, 20, 40)
    assert y.shape == (1, 2, 20, 40)
    assert float(y[0, 0, 5, 15]) == 1.0 and float(y[0, 0, 15, 15]) < 1e-6
    assert float(y[0, 1, 5, 5]) == 1.0 and float(y[0, 1, 5, 15]) < 1e-6


@pytest.mark.slow
def test_train_command_tiny(tmp_path, capsys):
    import json

    from graphtrack.cli import main
    from graphtrack.detect.learned import LearnedDetector

    torch.set_num_threads(1)
    out = tmp_path / "w.pt"
    assert main(["train", "--out", str(out), "--frames", "4", "--epochs", "1", "--batch", "4"]) == 0
    summary = json.loads(next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("{")))
    assert summary["data"]["frames"] == 4                  # an object, not JSON text inside the JSON
    det = LearnedDetector(out)
    d = det.detect(np.random.default_rng(0).integers(0, 255, (540, 960, 3), dtype=np.uint8))
    assert d.heatmap.shape == (540, 960)


def test_train_command_bad_args(tmp_path, capsys):
    from graphtrack.cli import main

    assert main(["train", "--out", str(tmp_path / "no" / "w.pt"), "--frames", "2"]) == 2
    assert main(["train", "--out", str(tmp_path / "w.pt"), "--frames", "0"]) == 2


@pytest.mark.slow
def test_train_init_fine_tunes_from_weights(tmp_path):
    # one epoch at a vanishing learning rate from --init: the written weights are the
    # initial ones (to 1e-6; the normalisation statistics move with the data), and the
    # metadata holds the command that made them
    from graphtrack.cli import main
    from graphtrack.detect.learned import DEFAULT_WEIGHTS

    torch.set_num_threads(1)
    out = tmp_path / "w.pt"
    assert main(["train", "--out", str(out), "--frames", "2", "--epochs", "1", "--init", str(DEFAULT_WEIGHTS),
                 "--lr", "1e-12", "--quiet"]) == 0
    new = torch.load(out, weights_only=True)
    old = torch.load(DEFAULT_WEIGHTS, weights_only=True)
    learned = [k for k in old["state_dict"] if "running_" not in k and "num_batches" not in k]
    assert learned
    for k in learned:
        torch.testing.assert_close(new["state_dict"][k], old["state_dict"][k], atol=1e-6, rtol=0)
    assert new["meta"]["init"] == str(DEFAULT_WEIGHTS)
    assert f"--init {DEFAULT_WEIGHTS}" in new["meta"]["command"] and "--lr 1e-12" in new["meta"]["command"]
    assert main(["train", "--out", str(out), "--frames", "2", "--init", str(tmp_path / "none.pt")]) == 2
