"""Tests of histostudy.learning.training._losses: the angle loss of §II-B.4 and the soft Dice loss."""

import numpy as np
import pytest
import torch

from histostudy.learning.training._losses import angle_loss, dice_loss


def test_angle_loss_wraps_azimuth_and_weights_it_by_sin_elevation():
    t = torch.tensor([[np.radians(-179.0), np.pi / 2]])
    p = torch.tensor([[np.radians(179.0), np.pi / 2]])
    assert float(angle_loss(p, t)) == pytest.approx(np.radians(2.0) ** 2, rel=1e-5)
    t0 = torch.tensor([[0.3, 0.0]])
    assert float(angle_loss(torch.tensor([[2.5, 0.1]]), t0)) == pytest.approx(0.01, rel=1e-5)  # azimuth moot on axis


def test_dice_loss_against_a_hand_computed_dice():
    labels = torch.tensor([[[0, 1, 1], [3, 3, 0]]])
    perfect = torch.nn.functional.one_hot(labels, 6).permute(0, 3, 1, 2).to(torch.float64) * 60.0
    # a perfect prediction: Dice 1 for the present classes and eps / (0 + eps) = 1 for the absent
    assert float(dice_loss(perfect, labels)) == pytest.approx(0.0, abs=1e-12)
    # uniform logits: p = 1/6 everywhere; class k with n_k pixels of 6: (2 n/6 + 1) / (6/6 + n + 1)
    uniform = torch.zeros(1, 6, 2, 3, dtype=torch.float64)
    expected = [(2 * n / 6 + 1) / (1 + n + 1) for n in (2, 0, 2, 0, 0)]
    assert float(dice_loss(uniform, labels)) == pytest.approx(1 - np.mean(expected), rel=1e-12)
