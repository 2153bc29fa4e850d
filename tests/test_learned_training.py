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


@pytest.mark.parametrize("deg", [30.0, -75.0, 150.0])
def test_turned_samples_keep_their_labels_on_their_lines(deg):
    # oracle: a line drawn by OpenCV into the image; after the turn its bright pixels lie
    # on the turned label (within a pixel), and the label stays inside the image
    import cv2

    from graphtrack.training.fit import turn_samples

    h, w = 60, 100
    img = np.zeros((h, w), np.float32)
    cv2.line(img, (30, 30), (70, 30), 1.0, 1)
    x = torch.from_numpy(img)[None, None].repeat(1, 3, 1, 1)
    segs = np.array([[[30.0, 30.0, 70.0, 30.0], [np.nan] * 4]])
    xt, st = turn_samples(x, segs, np.radians([deg]), h, w)
    assert np.all(np.isnan(st[0, 1]))
    a, b = st[0, 0, :2], st[0, 0, 2:]
    assert np.hypot(*(b - a)) == pytest.approx(40.0, abs=1e-6)   # inside: not clipped, length kept
    n = np.array([a[1] - b[1], b[0] - a[0]]) / 40.0
    ys, xs = np.nonzero(xt[0, 0].numpy() > 0.5)
    assert len(xs) > 20 and np.abs((np.stack([xs, ys], 1) - a) @ n).max() < 1.0
    # the turn's direction: content turns clockwise on screen for a positive angle (y down)
    d = (b - a) / 40.0
    assert d == pytest.approx([np.cos(np.radians(deg)), np.sin(np.radians(deg))], abs=1e-9)


def test_a_turned_label_is_clipped_to_the_image():
    from graphtrack.training.fit import turn_samples

    h, w = 60, 100
    x = torch.zeros(1, 3, h, w)
    segs = np.array([[[0.0, 29.5, 99.0, 29.5]]])        # the full width, turned upright: cut at the image
    _, st = turn_samples(x, segs, np.radians([90.0]), h, w)
    s = st[0, 0]
    assert np.all(s[0::2] >= -1e-9) and np.all(s[0::2] <= w - 1 + 1e-9)
    assert np.all(s[1::2] >= -1e-9) and np.all(s[1::2] <= h - 1 + 1e-9)
    assert abs(s[3] - s[1]) == pytest.approx(h - 1, abs=1e-6) and abs(s[2] - s[0]) < 1e-6
