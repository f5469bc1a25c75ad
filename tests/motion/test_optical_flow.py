"""Dense optical flow (DIS, RAFT checkpoints) and the forward-backward consistency check."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _flow_helpers import texture

from radar4dgs.motion.optical_flow import build_raft, consistency_mask, dis_flow, load_raft, raft_flow

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")

H, W = 60, 80


def test_dis_recovers_a_known_shift():
    big = texture(220, 360)
    a = np.ascontiguousarray(big[20:200, 20:340])
    b = np.ascontiguousarray(big[18:198, 17:337])  # content moves by (+3, +2) pixels
    for preset in ("fast", "medium"):
        flow = dis_flow(a, b, preset)
        assert flow.shape == (180, 320, 2) and flow.dtype == np.float32
        interior = flow[20:-20, 20:-20].reshape(-1, 2)
        assert np.median(interior, axis=0) == pytest.approx([3.0, 2.0], abs=0.1)
    rgb = np.repeat(a[..., None], 3, axis=2)
    assert np.allclose(dis_flow(rgb, np.repeat(b[..., None], 3, axis=2)), dis_flow(a, b))


def test_dis_on_resized_images_gives_the_full_size_flow():
    """With ``max_width`` DIS sees the images at that width; its flow is brought back to the full size
    and scale, so a 640-px pair shifted by (+24, +8) px reads (24, 8) everywhere inside."""
    big = texture(420, 720)
    a = np.ascontiguousarray(big[30:390, 40:680])
    b = np.ascontiguousarray(big[22:382, 16:656])  # content moves by (+24, +8) pixels
    flow = dis_flow(a, b, "medium", max_width=320)
    assert flow.shape == (360, 640, 2) and flow.dtype == np.float32
    assert np.median(flow[40:-40, 60:-60].reshape(-1, 2), axis=0) == pytest.approx([24.0, 8.0], abs=0.3)
    np.testing.assert_array_equal(dis_flow(a, b, "medium", max_width=640), dis_flow(a, b, "medium"))


def test_consistency_mask_constant_flows():
    forward = np.zeros((H, W, 2), np.float32)
    forward[..., 0] = 3.0
    backward = -forward
    mask = consistency_mask(forward, backward)
    assert mask[:, : W - 3].all() and not mask[:, W - 3:].any()  # the last columns leave the image
    wrong = backward.copy()
    wrong[..., 1] = 2.0  # |f_fw + f_bw|^2 = 4 > 0.01 * (9 + 13) + 0.5
    assert not consistency_mask(forward, wrong).any()
    slightly = backward + 0.5  # residual 0.5 px^2 ... (0.5^2 + 0.5^2) = 0.5 < 0.01 * (9 + 6.5) + 0.5
    assert consistency_mask(forward, slightly)[:, : W - 3].all()


@pytest.fixture(scope="module")
def raft_checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    network = build_raft("small")
    path = tmp_path_factory.mktemp("raft") / "raft_small.pth"
    torch.save(network.state_dict(), path)
    return path, network


def test_raft_checkpoint_loads_and_matches_the_network(raft_checkpoint, tmp_path):
    path, network = raft_checkpoint
    loaded = load_raft(path, "small")
    for (name, a), b in zip(network.state_dict().items(), loaded.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
    a = np.repeat(texture(36, 44)[..., None], 3, axis=2)  # not a multiple of 8: exercises padding
    b = np.roll(a, 2, axis=1)
    flow = raft_flow(loaded, a, b, iterations=2)
    assert flow.shape == (36, 44, 2) and np.isfinite(flow).all()
    # wrapped checkpoints ("state_dict", DataParallel "module." prefix) load too
    wrapped = tmp_path / "wrapped.pth"
    torch.save({"state_dict": {f"module.{k}": v for k, v in network.state_dict().items()}}, wrapped)
    again = load_raft(wrapped, "small")
    assert np.allclose(raft_flow(again, a, b, iterations=2), flow, atol=1e-5)


def test_raft_errors_name_the_problem(raft_checkpoint, tmp_path):
    path, _ = raft_checkpoint
    with pytest.raises(FileNotFoundError, match="RAFT checkpoint not found"):
        load_raft(tmp_path / "missing.pth")
    with pytest.raises(ValueError, match="not a torchvision raft_large state dict"):
        load_raft(path, "large")
