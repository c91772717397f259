"""The float16 round trip of a trained network (learning/training_export.py): what a lent GPU
sends back and what is widened again here."""

import json

import numpy as np
import pytest
import torch

from histostudy.learning import full_precision_copy, half_precision_copy
from histostudy.learning.checkpoints import load_checkpoint, load_network, save_checkpoint
from histostudy.learning.nets.unet import UNet


def _saved(tmp_path, scale=1.0):
    torch.manual_seed(0)
    net = UNet(base_width=8, depth=2)
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(scale)
    tensors = {f"model.{k}": v for k, v in net.state_dict().items()}
    return net, save_checkpoint(tmp_path / "unet", tensors, net.config, profile="standard", seed=7,
                                training_steps=40, validation={"loss": 0.25})


def test_a_half_precision_copy_is_half_the_size_and_widens_to_the_rounded_network(tmp_path):
    net, mpath = _saved(tmp_path)
    source = json.loads(mpath.read_text())
    half = half_precision_copy(tmp_path / "unet.safetensors", tmp_path / "out" / "unet")
    tensors, manifest = load_checkpoint(half.with_suffix(".safetensors"))
    assert all(t.dtype == torch.float16 for t in tensors.values() if t.is_floating_point())
    assert manifest["float16_of"] == source["sha256"] and manifest["validation"] == {"loss": 0.25}
    assert manifest["training_steps"] == 40 and manifest["config"] == source["config"]
    assert manifest["size_bytes"] < 0.6 * source["size_bytes"]  # the header is not halved

    wide = full_precision_copy(half.with_suffix(".safetensors"), tmp_path / "back" / "unet")
    widened, wide_manifest = load_network(wide.with_suffix(".safetensors"))
    assert wide_manifest["rounded_to"] == "float16" and wide_manifest["float16_of"] == source["sha256"]
    for name, value in widened.state_dict().items():
        original = net.state_dict()[name]
        if original.is_floating_point():
            # each weight rounded once to float16: relative error at most 2^-11 (normal range)
            np.testing.assert_allclose(value.numpy(), original.numpy(), rtol=2.0**-11, atol=2.0**-24)
            assert torch.equal(value, original.half().float())
        else:
            assert torch.equal(value, original)
    x = torch.randn(1, 1, 32, 32)
    with torch.no_grad():
        assert torch.allclose(widened(x), net.eval()(x), atol=2e-2 * float(net(x).abs().max()))


def test_weights_beyond_float16s_range_are_refused(tmp_path):
    _saved(tmp_path, scale=1e6)
    with pytest.raises(ValueError, match="exceeds float16's range"):
        half_precision_copy(tmp_path / "unet.safetensors", tmp_path / "out" / "unet")
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
