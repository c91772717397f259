"""Tests of histostudy.learning.inference._int8: the U-Net in 8-bit integers, rebuilt from a stored
calibration, checked against the float network (its labels against the checkpoint's are in
test_runner.py, precision "int8")."""

import json

import numpy as np
import pytest
import torch

from histostudy.imaging import Frame, default_biplane
from histostudy.learning import UNetRunner, default_segmenter
from histostudy.learning.inference import runner
from histostudy.learning.inference._int8 import (
    INT8_CALIBRATION_FORMAT,
    Int8Features,
    calibrate_int8,
    int8_available,
    int8_calibration_path,
    load_int8_calibration,
    save_int8_calibration,
)
from histostudy.learning.nets.unet import UNet

pytestmark = pytest.mark.skipif(not int8_available(), reason="this torch has no oneDNN int8 kernels")


@pytest.fixture(scope="module")
def small_unet():
    torch.manual_seed(1)
    net = UNet(base_width=4, depth=2).eval()
    return UNetRunner(net, scale=0.5, manifest={"sha256": "ab" * 32, "weights_file": "small.safetensors"})


@pytest.fixture(scope="module")
def frames():
    """Three frames of smooth structure (a quarter-resolution view, 240 x 310)."""
    view = default_biplane()[0].scaled(0.25)
    rows, cols = np.mgrid[:view.shape[0], :view.shape[1]]
    rng = np.random.default_rng(3)
    out = []
    for k in range(3):
        image = np.sin(rows / (7.0 + k)) * np.cos(cols / 11.0) + 0.1 * rng.standard_normal(view.shape)
        out.append(Frame(image.astype(np.float32), view))
    return out


def _network_input(segmenter, frame):
    from histostudy.learning.preprocess import prepare_image

    x = torch.from_numpy(prepare_image(frame.image, segmenter.scale))[None, None]
    return x[..., :112, :152].contiguous(memory_format=torch.channels_last)


def test_int8_features_follow_the_float_network_and_rebuild_exactly(small_unet, frames):
    """Calibrated on the frames, the int8 features are the float ones to within a few quantisation
    steps of their range; built twice, or from the calibration's JSON, they are the same bits."""
    calibration = calibrate_int8(small_unet, frames)
    assert calibration["format"] == INT8_CALIBRATION_FORMAT and calibration["frames"] == 3
    assert calibration["checkpoint_sha256"] == "ab" * 32
    assert calibration["float_modules"][0] == "n.down.0.0" and all("up" in n for n in calibration["float_modules"][1:])
    int8 = Int8Features(small_unet, calibration)
    x = _network_input(small_unet, frames[0])
    with torch.no_grad():
        reference = small_unet.network.features(x)
    features = int8.features(x)
    assert features.dtype == torch.float32 and features.shape == reference.shape
    span = float(reference.max() - reference.min())
    error = (features - reference).abs()
    assert float(error.mean()) < 0.01 * span and float(error.max()) < 0.15 * span
    again = Int8Features(small_unet, json.loads(json.dumps(calibration))).features(x)
    torch.testing.assert_close(again, features, rtol=0, atol=0)


def test_calibrations_are_stored_beside_the_weights_and_checked(small_unet, frames, tmp_path):
    calibration = calibrate_int8(small_unet, frames[:1])
    path = save_int8_calibration(calibration, tmp_path / "small.int8.json")
    assert json.loads(path.read_text()) == calibration
    assert int8_calibration_path(small_unet).name == "small.int8.json"
    assert int8_calibration_path(UNetRunner(small_unet.network)) is None  # no manifest: nowhere
    with pytest.raises(ValueError, match=r"calibration is of the checkpoint with SHA-256 'cd"):
        Int8Features(small_unet, calibration | {"checkpoint_sha256": "cd" * 32})
    with pytest.raises(ValueError, match=r"calibration must be a dict of format 'histostudy.int8-calibration/1'"):
        Int8Features(small_unet, calibration | {"format": "other/1"})
    with pytest.raises(ValueError, match=r"calibration holds 2 activations"):
        Int8Features(small_unet, calibration | {"activation_qparams": calibration["activation_qparams"][:2]})
    with pytest.raises(ValueError, match=r"activation_qparams'\] must be a list of \[scale > 0"):
        Int8Features(small_unet, calibration | {"activation_qparams": [[0.0, 3]]})
    with pytest.raises(ValueError, match="frames must be a non-empty sequence of Frames"):
        calibrate_int8(small_unet, [])
    with pytest.raises(ValueError, match=r"precision 'int8' needs the calibration of this checkpoint"):
        small_unet.with_precision("int8")


def test_the_shipped_unet_has_its_calibration_and_int8_is_asked_for_by_name(small_unet, monkeypatch):
    """data/models/unet_standard.int8.json is of the shipped weights (same SHA-256); "auto" is
    bfloat16 where it is native and float32 elsewhere, never int8."""
    shipped = default_segmenter()
    if shipped is None:
        pytest.skip("the shipped U-Net (data/models/unet_standard) is not available")
    calibration = load_int8_calibration(shipped)
    assert calibration is not None and calibration["checkpoint_sha256"] == shipped.manifest["sha256"]
    assert calibration["frames"] >= 8
    monkeypatch.setattr(runner, "native_bfloat16", lambda: False)
    assert shipped.with_precision("auto").precision == small_unet.with_precision("auto").precision == "float32"
    assert shipped.with_precision("int8").precision == "int8"
    monkeypatch.setattr(runner, "native_bfloat16", lambda: True)
    assert shipped.with_precision("auto").precision == "bfloat16"
    with pytest.raises(TypeError, match="segmenter must be a histostudy.learning.UNetRunner"):
        calibrate_int8("unet", [])
