"""The learned detector: network, segment extraction, shipped weights, bad files, sold2 adapter."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from graphtrack.errors import InputError


@pytest.fixture(scope="module")
def detector():
    from graphtrack.detect.learned import LearnedDetector

    torch.set_num_threads(1)
    return LearnedDetector()


def test_forward_shapes():
    from graphtrack.detect.learned_net import LineNet

    net = LineNet().eval()
    for h, w in ((135, 240), (33, 47), (8, 8)):
        with torch.inference_mode():
            y = net(torch.rand(2, 3, h, w))
        assert y.shape == (2, 2, h, w)
    fused = net.fused()
    x = torch.rand(1, 3, 40, 64)
    with torch.inference_mode():
        assert torch.allclose(net(x), fused(x), atol=1e-4)
    assert sum(p.numel() for p in net.parameters()) < 100_000


def test_pointwise_product_equals_the_1x1_convolution():
    """Pointwise computes F.conv2d's 1x1 convolution on NCHW and channels-last input in
    both orientations (X W^T, and W X^T for narrow layers); X W^T keeps channels-last output
    channels-last, W X^T gives NCHW unless asked for channels-last."""
    from torch import nn

    from graphtrack.detect.learned_net import Pointwise

    g = torch.Generator().manual_seed(1)
    conv = nn.Conv2d(5, 3, 1)
    with torch.no_grad():
        conv.weight.copy_(torch.randn(3, 5, 1, 1, generator=g))
        conv.bias.copy_(torch.randn(3, generator=g))
    x = torch.randn(2, 5, 7, 9, generator=g)
    nhwc = x.contiguous(memory_format=torch.channels_last)
    with torch.inference_mode():
        ref = torch.nn.functional.conv2d(x, conv.weight, conv.bias)
        for pw in (Pointwise(conv), Pointwise(conv, transposed=True),
                   Pointwise(conv, transposed=True, channels_last=True)):
            for inp in (x, nhwc):
                y = pw(inp)
                assert y.shape == ref.shape
                np.testing.assert_allclose(y.numpy(), ref.numpy(), rtol=0, atol=1e-5)
        assert Pointwise(conv)(nhwc).is_contiguous(memory_format=torch.channels_last)
        assert Pointwise(conv, transposed=True)(x[:1]).is_contiguous()
        assert Pointwise(conv, transposed=True, channels_last=True)(x).is_contiguous(
            memory_format=torch.channels_last)


def test_traced_net_computes_what_the_eager_net_computes():
    """The detector runs a torch.jit trace of the fused net (speed); on any input size
    (the trace was made at another) its maps equal the eager module's to 1e-4 (the NHWC kernels
    sum in another order)."""
    from graphtrack.detect.learned import DEFAULT_WEIGHTS, load_weights, traced_net

    net = load_weights(DEFAULT_WEIGHTS)
    traced = traced_net(net, ("test", 0), (135, 240))
    assert traced is not None
    g = torch.Generator().manual_seed(0)
    with torch.inference_mode():
        for h, w in ((135, 240), (135, 240), (68, 120), (33, 47), (270, 480)):
            x = torch.rand(1, 3, h, w, generator=g)
            ref = net(x)
            for _ in range(3):   # the profiling executor optimises after its first runs
                np.testing.assert_allclose(traced(x).numpy(), ref.numpy(), rtol=0, atol=1e-4)


def test_detector_falls_back_to_the_eager_net_when_tracing_fails(monkeypatch):
    from graphtrack.detect import learned

    def refuse(*a, **k):
        raise RuntimeError("no tracing here")

    monkeypatch.setattr(learned.torch.jit, "trace", refuse)
    monkeypatch.setattr(learned, "_TRACED", {})
    det = learned.LearnedDetector()
    img = np.zeros((64, 96, 3), np.uint8)
    img[:, 40:56] = 200
    L, J = det.heatmaps(img)
    assert det._infer is det.net and L.shape == (16, 24) and J.shape == (16, 24)


def test_shipped_weights_detect_both_edges_on_unseen_frame(detector):
    from graphtrack.geometry.lines import line_difference
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    sim = Simulation("structured", 10, seed=4242, size=(540, 960))
    raw, _ = sim.render(5)
    und = sim.camera.undistort(raw)
    det = detector.detect(und)
    assert det.heatmap.shape == und.shape[:2] and det.heatmap.dtype == np.float32
    assert 0.0 <= det.heatmap.min() and det.heatmap.max() <= 1.0
    rho, th, ok = shaft_lines(base_features(sim.robot, sim.q_read[5]).transformed(sim.E_t[5]), sim.camera.K)
    assert ok
    assert len(det.shaft_lines) == 2
    for r, t in det.shaft_lines:
        dr, dt = line_difference(r, t, rho, th)
        j = int(np.argmin(np.abs(dt) + np.abs(dr) / 100))
        assert abs(dr[j]) < 5.0 and abs(dt[j]) < 0.03
    # with the true lines as prediction, each edge is labelled by its own line
    det2 = detector.detect(und, np.stack([rho, th], 1))
    assert sorted(det2.edge_ids.tolist()) == [0, 1]


def test_subpixel_refinement_puts_the_shaft_lines_on_the_true_limbs(detector):
    # oracle: the limb lines of the simulator's true pose (Chaumette's projection)
    from graphtrack.detect.learned import LearnedDetector
    from graphtrack.geometry.lines import line_difference
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    sim = Simulation("structured", 10, seed=4242, size=(540, 960))
    coarse = LearnedDetector(subpixel=False)
    err = {"refined": [], "coarse": []}
    for k in (2, 5, 8):
        raw, _ = sim.render(k)
        und = sim.camera.undistort(raw)
        rho, th, _ = shaft_lines(base_features(sim.robot, sim.q_read[k]).transformed(sim.E_t[k]), sim.camera.K)
        for name, det in (("refined", detector.detect(und, np.stack([rho, th], 1))),
                          ("coarse", coarse.detect(und, np.stack([rho, th], 1)))):
            assert len(det.shaft_lines) == 2
            for (r, t), j in zip(det.shaft_lines, det.edge_ids):
                dr, dt = line_difference(r, t, rho[j], th[j])
                err[name].append((abs(dr), abs(dt)))
    refined, coarse_err = np.array(err["refined"]), np.array(err["coarse"])
    assert refined[:, 0].max() < 0.3 and refined[:, 1].max() < 1e-3
    assert np.median(refined[:, 0]) < 0.5 * np.median(coarse_err[:, 0])


def test_detection_on_the_raw_frame_is_in_undistorted_pixels(detector):
    # oracle: the simulator's true limb lines (undistorted pixels); markers: those found
    # on the fully undistorted frame. The raw frame is never undistorted whole.
    from graphtrack.geometry.lines import line_difference
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    sim = Simulation("structured", 10, seed=4242, size=(540, 960))
    assert np.any(sim.camera.dist != 0)
    for k in (2, 5, 8):
        raw, _ = sim.render(k)
        rho, th, _ = shaft_lines(base_features(sim.robot, sim.q_read[k]).transformed(sim.E_t[k]), sim.camera.K)
        det = detector.detect(raw, np.stack([rho, th], 1), camera=sim.camera)
        assert len(det.shaft_lines) == 2 and det.heatmap.shape == raw.shape[:2]
        for (r, t), j in zip(det.shaft_lines, det.edge_ids):
            dr, dt = line_difference(r, t, rho[j], th[j])
            assert abs(dr) < 0.3 and abs(dt) < 1e-3
        ref = detector.detect(sim.camera.undistort(raw)).markers
        assert len(det.markers) == len(ref) > 0
        for m in det.markers:
            assert np.min(np.hypot(*(ref - m).T)) < 0.5


@pytest.mark.parametrize("kind", ["black", "white", "tiny", "grey2d"])
def test_degenerate_frames(detector, kind):
    img = {"black": np.zeros((540, 960, 3), np.uint8), "white": np.full((540, 960, 3), 255, np.uint8),
           "tiny": np.full((5, 7, 3), 90, np.uint8), "grey2d": np.zeros((20, 30), np.uint8)}[kind]
    det = detector.detect(img)
    assert len(det.shaft_lines) == 0 and len(det.segments) == 0


def test_bad_weight_files(tmp_path):
    from graphtrack.detect.learned import load_weights
    from graphtrack.detect.learned_net import LineNet

    with pytest.raises(InputError, match="not found"):
        load_weights(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="junk.pt"):
        load_weights(junk)
    notsd = tmp_path / "list.pt"
    torch.save([1, 2, 3], notsd)
    with pytest.raises(InputError, match="not a state dict"):
        load_weights(notsd)
    wrong = tmp_path / "wrong.pt"
    torch.save(torch.nn.Linear(3, 4).state_dict(), wrong)
    with pytest.raises(InputError, match="architecture"):
        load_weights(wrong)
    other_width = tmp_path / "w8.pt"
    torch.save(LineNet(width=8).state_dict(), other_width)  # plain state dict, default width 16 expected
    with pytest.raises(InputError, match="architecture"):
        load_weights(other_width)


def test_cli_bad_weights_exit_2(tmp_path, capsys):
    from graphtrack.detect import make_detector

    with pytest.raises(InputError, match="missing.pt"):
        make_detector("learned", weights=str(tmp_path / "missing.pt"))


@pytest.mark.slow
def test_sold2_adapter_random_weights(tmp_path):
    from kornia.feature import SOLD2_detector   # kornia is a dependency (pyproject)

    from graphtrack.detect import make_detector
    from graphtrack.detect.sold2 import Sold2Detector

    torch.manual_seed(0)
    ckpt = tmp_path / "sold2.pt"
    torch.save(SOLD2_detector(pretrained=False).model.state_dict(), ckpt)
    det = make_detector("sold2", weights=str(ckpt))
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (60, 84, 3), dtype=np.uint8)
    d = det.detect(img)
    assert d.heatmap.shape == (60, 84) and 0 <= d.heatmap.min() and d.heatmap.max() <= 1
    assert d.segments.ndim == 2 and d.segments.shape[1] == 4
    assert len(det.detect(np.zeros((60, 84, 3), np.uint8)).shaft_lines) == 0
    with pytest.raises(InputError):
        Sold2Detector()
    bad = tmp_path / "bad.pt"
    torch.save({"a": torch.zeros(3)}, bad)
    with pytest.raises(InputError, match="architecture"):
        Sold2Detector(weights=bad)


def test_refined_edges_pixel_sets_lie_on_the_true_limbs(detector):
    """The learned detector marks the edges its refinement moved (Detection.refined, one
    flag per shaft segment, kept by scale_detection; all False without the refinement);
    their line-intensities sets, carried onto the refined segments, lie on the true
    limbs (the simulator's projection) to half a pixel and are not bands; without the
    refinement every set is a band. (That a band off the edge is carried onto it:
    test_detect_observe.py.)"""
    from graphtrack.detect import make_observation
    from graphtrack.detect.learned import LearnedDetector
    from graphtrack.detect.observe import scale_detection
    from graphtrack.geometry.lines import pixel_residual
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    sim = Simulation("tissue", 10, seed=4243, size=(540, 960))
    coarse = LearnedDetector(subpixel=False)
    offsets = []
    for k in (2, 5, 8):
        raw, _ = sim.render(k)
        und = sim.camera.undistort(raw)
        rho, th, _ = shaft_lines(base_features(sim.robot, sim.q_read[k]).transformed(sim.E_t[k]), sim.camera.K)
        unrefined = coarse.detect(und, np.stack([rho, th], 1))
        assert len(unrefined.refined) == len(unrefined.shaft_segments) == 2 and not unrefined.refined.any()
        assert make_observation(unrefined, "line-intensities").bands.tolist() == [True, True]
        det = detector.detect(und, np.stack([rho, th], 1))
        assert len(det.refined) == len(det.shaft_segments) == 2 and det.refined.all()
        np.testing.assert_array_equal(scale_detection(det, 0.5).refined, det.refined)
        obs = make_observation(det, "line-intensities")
        assert obs.bands.tolist() == [False, False]
        offsets += [abs(np.median(pixel_residual(pts, rho[j], th[j]))) for pts, j in zip(obs.pixels, obs.edge_ids)]
    assert len(offsets) == 6 and max(offsets) < 0.5
