"""Tests of histostudy.learning.inference._head_argmax: the U-Net's 1x1 head and the arg-max over its classes in
one pass, against torch's convolution and arg-max."""

import numpy as np
import pytest
import torch

from histostudy.learning.inference._head_argmax import head_argmax


def _torch_labels(features, weight, bias):
    x = torch.from_numpy(features).permute(2, 0, 1)[None]
    logits = torch.nn.functional.conv2d(x, torch.from_numpy(weight)[:, :, None, None], torch.from_numpy(bias))[0]
    return logits.argmax(dim=0).numpy(), logits.numpy()


@pytest.mark.parametrize("shape", [(37, 53, 8), (1, 300, 8), (16, 16, 3)])
def test_labels_are_torchs_arg_max_of_the_head(shape):
    rng = np.random.default_rng(4)
    features = rng.normal(size=shape).astype(np.float32)
    weight = rng.normal(size=(6, shape[2])).astype(np.float32)
    bias = rng.normal(size=6).astype(np.float32)
    got = head_argmax(features, weight, bias)
    expected, logits = _torch_labels(features, weight, bias)
    assert got.dtype == np.uint8 and got.shape == shape[:2]
    # an ulp of a different summation order can move an arg-max only at a near-tie
    top2 = np.sort(logits, axis=0)[-2:]
    clear = top2[1] - top2[0] > 1e-5 * np.abs(top2[1]).clip(1.0)
    assert clear.mean() > 0.99
    assert np.array_equal(got[clear], expected[clear])


def test_bfloat16_bits_are_widened_exactly():
    rng = np.random.default_rng(5)
    wide = torch.from_numpy(rng.normal(size=(20, 30, 8)).astype(np.float32)).to(torch.bfloat16)
    weight = rng.normal(size=(6, 8)).astype(np.float32)
    bias = rng.normal(size=6).astype(np.float32)
    from_bits = head_argmax(wide.view(torch.uint16).numpy(), weight, bias)
    assert np.array_equal(from_bits, head_argmax(wide.float().numpy(), weight, bias))


def test_ties_go_to_the_first_class_as_in_torch():
    features = np.ones((4, 5, 2), np.float32)
    weight = np.array([[0.0, 1.0], [1.0, 0.0], [0.5, 0.5], [1.0, 0.0]], np.float32)
    bias = np.zeros(4, np.float32)  # classes 0, 1 and 3 tie at 1, class 2 too (0.5 + 0.5)
    assert not head_argmax(features, weight, bias).any()
    bias[3] = 1.0
    assert (head_argmax(features, weight, bias) == 3).all()
    assert np.array_equal(head_argmax(features, weight, bias), _torch_labels(features, weight, bias)[0])


@pytest.mark.parametrize("features, weight, bias, match", [
    (np.zeros((4, 4, 8), np.float64), np.zeros((6, 8), np.float32), np.zeros(6, np.float32), "features"),
    (np.zeros((4, 8), np.float32), np.zeros((6, 8), np.float32), np.zeros(6, np.float32), "features"),
    (np.zeros((4, 4, 8), np.float32), np.zeros((6, 7), np.float32), np.zeros(6, np.float32), "weight"),
    (np.zeros((4, 4, 8), np.float32), np.zeros((6, 8), np.float32), np.zeros(5, np.float32), "bias"),
])
def test_bad_shapes_and_dtypes_are_refused(features, weight, bias, match):
    with pytest.raises(ValueError, match=match):
        head_argmax(features, weight, bias)
