"""Exposure compensation (issue 27): the per-frame affine colour transform is the identity at
test time and before training, and recovers a known exposure change."""

from __future__ import annotations

import torch

from radar4dgs.model.appearance import FrameAppearance, affine_colors


def test_the_transform_is_the_identity_at_test_time_and_at_initialisation():
    appearance = FrameAppearance(4)
    rgb = torch.rand(5, 6, 3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        appearance.matrix[2] = torch.randn(3, 3) * 0.1
        appearance.bias[2] = torch.tensor([0.1, -0.2, 0.05])
    assert appearance(rgb, None) is rgb  # a test view has no learned transform
    assert torch.equal(appearance(rgb, 0), rgb)  # untrained rows are exactly the identity
    expected = rgb @ (torch.eye(3) + appearance.matrix[2]).T + appearance.bias[2]
    torch.testing.assert_close(appearance(rgb, 2), expected)
    with torch.no_grad():  # mean over the 4 frames of the squared deviation from the identity
        expected_reg = (appearance.matrix[2] ** 2).sum() / 4 + (appearance.bias[2] ** 2).sum() / 4
        torch.testing.assert_close(appearance.regularizer(), expected_reg)


def test_a_known_exposure_change_is_recovered():
    """Frame 1 rendered 30 % darker with a blue tint: fitting its transform alone finds the gains."""
    rgb = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(1))
    gain, offset = torch.tensor([0.7, 0.7, 0.75]), torch.tensor([0.0, 0.0, 0.02])
    target = rgb * gain + offset
    appearance = FrameAppearance(3)
    optimiser = torch.optim.Adam(appearance.parameters(), lr=0.02)
    for _ in range(400):
        loss = (appearance(rgb, 1) - target).abs().mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    torch.testing.assert_close(appearance.gains()[1], gain, atol=0.02, rtol=0)
    torch.testing.assert_close(appearance.bias[1].detach(), offset, atol=0.02, rtol=0)
    assert torch.equal(appearance.gains()[0], torch.ones(3))  # other frames untouched (no gradient)


def test_state_round_trip():
    appearance = FrameAppearance(2)
    with torch.no_grad():
        appearance.matrix.normal_()
        appearance.bias.normal_()
    copy = FrameAppearance.from_state(appearance.state())
    assert torch.equal(copy.matrix, appearance.matrix) and torch.equal(copy.bias, appearance.bias)
    assert torch.equal(affine_colors(torch.ones(1, 1, 3), copy.matrix[0], copy.bias[0]),
                       affine_colors(torch.ones(1, 1, 3), appearance.matrix[0], appearance.bias[0]))
