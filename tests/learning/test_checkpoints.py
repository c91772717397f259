"""Checkpoints: safetensors + JSON manifest, hash and config checks, atomic writes, shipped models."""

import hashlib
import json

import pytest
import torch

from histostudy.learning import checkpoints, shipped_model
from histostudy.learning.checkpoints import load_checkpoint, load_network, manifest_path, save_checkpoint
from histostudy.learning.nets.unet import UNet

CONFIG = {"arch": "unet", "in_channels": 1, "n_classes": 6, "base_width": 2, "depth": 2}


def _save(path, net=None, **extra):
    net = net or UNet(base_width=2, depth=2)
    tensors = {f"model.{k}": v for k, v in net.state_dict().items()}
    return net, save_checkpoint(path, tensors, net.config, profile="smoke", seed=7, training_steps=3, **extra)


def test_weights_exported_into_the_repository_record_its_clean_commit(tmp_path, monkeypatch):
    """Overwriting tracked weights must not make the manifest call the tree it came from modified."""
    import shutil
    import subprocess

    from histostudy.core.provenance import git_commit

    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    repo = tmp_path / "repo"
    (repo / "models").mkdir(parents=True)
    torch.manual_seed(0)
    _save(repo / "models" / "unet")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(repo)]
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    subprocess.run(git + ["add", "."], check=True)
    subprocess.run(git + ["commit", "-qm", "weights"], check=True)
    head = subprocess.run(git + ["rev-parse", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()
    monkeypatch.setattr(checkpoints, "git_commit", lambda: git_commit(repo))
    torch.manual_seed(1)
    _, mpath = _save(repo / "models" / "unet")  # new weights over the tracked ones
    assert json.loads(mpath.read_text())["git_commit"] == head
    assert git_commit(repo) == head + "-dirty"  # the tree is modified now, by the export


def test_roundtrip_manifest_and_hash(tmp_path):
    torch.manual_seed(0)
    net, mpath = _save(tmp_path / "unet", validation={"loss": 0.5})
    weights = tmp_path / "unet.safetensors"
    manifest = json.loads(mpath.read_text())
    assert mpath == manifest_path(weights) == tmp_path / "unet.json"
    assert manifest["sha256"] == hashlib.sha256(weights.read_bytes()).hexdigest()
    assert manifest["config"] == CONFIG and manifest["profile"] == "smoke" and manifest["seed"] == 7
    assert manifest["training_steps"] == 3 and manifest["validation"] == {"loss": 0.5}
    assert manifest["git_commit"]
    loaded, _ = load_network(weights)
    x = torch.randn(1, 1, 20, 24)
    torch.testing.assert_close(loaded(x), net.eval()(x))
    raw = weights.read_bytes()  # safetensors: 8-byte little-endian header length, JSON header, raw data
    header = json.loads(raw[8:8 + int.from_bytes(raw[:8], "little")])
    assert json.loads(header["__metadata__"]["config"]) == CONFIG
    assert not list(tmp_path.glob("*.tmp*"))


def test_changed_weights_fail_the_hash(tmp_path):
    _save(tmp_path / "unet")
    weights = tmp_path / "unet.safetensors"
    data = bytearray(weights.read_bytes())
    data[-5] ^= 0xFF
    weights.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="SHA-256.*changed or damaged"):
        load_checkpoint(weights)


def test_corrupt_file_with_matching_hash_is_reported(tmp_path):
    _save(tmp_path / "unet")
    weights = tmp_path / "unet.safetensors"
    weights.write_bytes(b"not a safetensors file at all")
    m = json.loads(manifest_path(weights).read_text())
    m["sha256"] = hashlib.sha256(weights.read_bytes()).hexdigest()
    manifest_path(weights).write_text(json.dumps(m))
    with pytest.raises(ValueError, match="not a valid safetensors"):
        load_checkpoint(weights)


def test_config_mismatch_is_reported(tmp_path):
    _save(tmp_path / "unet")
    weights = tmp_path / "unet.safetensors"
    with pytest.raises(ValueError, match="expected"):
        load_checkpoint(weights, expected_config={**CONFIG, "base_width": 4})
    m = json.loads(manifest_path(weights).read_text())
    m["config"]["base_width"] = 4  # the manifest now disagrees with the weights' own header
    manifest_path(weights).write_text(json.dumps(m))
    with pytest.raises(ValueError, match="saved for config"):
        load_checkpoint(weights)


def test_weights_that_do_not_fit_their_config(tmp_path):
    net = UNet(base_width=4, depth=2)
    tensors = {f"model.{k}": v for k, v in net.state_dict().items()}
    save_checkpoint(tmp_path / "bad", tensors, CONFIG)  # a base_width 2 config for width-4 tensors
    with pytest.raises(ValueError, match="does not fit its config"):
        load_network(tmp_path / "bad.safetensors")


def test_missing_manifest_or_weights(tmp_path):
    _save(tmp_path / "unet")
    manifest_path(tmp_path / "unet.safetensors").unlink()
    with pytest.raises(ValueError, match="no manifest"):
        load_checkpoint(tmp_path / "unet.safetensors")
    with pytest.raises(ValueError, match="does not exist"):
        load_checkpoint(tmp_path / "nothing.safetensors")


def test_a_failed_write_leaves_nothing_half_written(tmp_path, monkeypatch):
    net, _ = _save(tmp_path / "unet")
    before = (tmp_path / "unet.safetensors").read_bytes()

    def broken(tensors, filename, metadata=None):
        with open(filename, "wb") as fh:
            fh.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(checkpoints, "save_file", broken)
    with pytest.raises(OSError, match="disk full"):
        _save(tmp_path / "unet", net)
    assert (tmp_path / "unet.safetensors").read_bytes() == before
    load_checkpoint(tmp_path / "unet.safetensors")  # still valid with its manifest
    assert not list(tmp_path.glob(".*tmp*"))


def test_shipped_model_lookup(tmp_path):
    assert shipped_model("unet", models_dir=tmp_path) is None
    _save(tmp_path / "unet")
    assert shipped_model("unet", models_dir=tmp_path) == tmp_path / "unet.safetensors"
    data = bytearray((tmp_path / "unet.safetensors").read_bytes())
    data[-1] ^= 1
    (tmp_path / "unet.safetensors").write_bytes(bytes(data))
    with pytest.warns(UserWarning, match="not usable"):
        assert shipped_model("unet", models_dir=tmp_path) is None


def test_training_summary_reads_the_manifests_training_record():
    from histostudy.learning import training_summary

    manifest = {"training_steps": 1200, "init_weights": {"sha256": "ab" * 32, "training_steps": 600},
                "training_config": {"optimizer": "adam", "n_train": 3000, "render": {"render_spacing_mm": 0.47},
                                    "fine_tune": {"n_train": 1500, "render": {"render_spacing_mm": 0.125}}}}
    assert training_summary(manifest) == (
        "1200 training steps (adam), on 3000 frames rendered from the 0.47 mm model, fine-tuned on 1500 frames "
        "rendered from the 0.125 mm model, started from a checkpoint of sha256 abababababab (600 steps)")
    assert training_summary({"training_steps": 40}) == "40 training steps"  # an older manifest: nothing guessed
    with pytest.raises(TypeError, match="manifest must be a checkpoint manifest dict"):
        training_summary("vgg19_standard.json")


def test_a_manifest_that_is_not_a_json_object(tmp_path):
    _save(tmp_path / "unet")
    manifest_path(tmp_path / "unet.safetensors").write_text(json.dumps(["histostudy.checkpoint", 1]))
    with pytest.raises(ValueError, match=r"unet\.json.*JSON list, expected a JSON object"):
        load_checkpoint(tmp_path / "unet.safetensors")
    # the shipped-model lookup keeps its documented contract: a warning and None, not a crash
    with pytest.warns(UserWarning, match=r"(?s)not usable.*JSON list, expected a JSON object"):
        assert shipped_model("unet", models_dir=tmp_path) is None


def _rewrite_weights(weights, edit_header):
    """Edit a safetensors file's header and re-hash its manifest, as a careless converter would:
    the hash check alone then lets it through."""
    raw = weights.read_bytes()
    n = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8:8 + n])
    edit_header(header)
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    weights.write_bytes(len(text).to_bytes(8, "little") + text + raw[8 + n:])
    m = json.loads(manifest_path(weights).read_text())
    m["sha256"] = hashlib.sha256(weights.read_bytes()).hexdigest()
    manifest_path(weights).write_text(json.dumps(m))
    return m


def test_relabelled_tensor_dtypes_are_refused(tmp_path):
    net, _ = _save(tmp_path / "unet")
    weights = tmp_path / "unet.safetensors"
    victim = next(k for k, v in net.state_dict().items() if v.dtype == torch.float32)
    manifest = json.loads(manifest_path(weights).read_text())
    assert manifest["tensor_dtypes"][f"model.{victim}"] == "float32"

    def relabel(header):  # same byte size: the float32 bits now read as int32
        assert header[f"model.{victim}"]["dtype"] == "F32"
        header[f"model.{victim}"]["dtype"] = "I32"

    m = _rewrite_weights(weights, relabel)
    with pytest.raises(ValueError, match=rf"tensor 'model\.{victim}' has dtype int32, but manifest .*records float32"):
        load_checkpoint(weights)
    # a manifest without the record (written before it, as the shipped ones): the network decides
    del m["tensor_dtypes"]
    manifest_path(weights).write_text(json.dumps(m))
    tensors, _ = load_checkpoint(weights)
    assert tensors[f"model.{victim}"].dtype == torch.int32
    with pytest.raises(ValueError, match=rf"tensor 'model\.{victim}' has dtype int32, but the network .* expects "
                                         r"float32"):
        load_network(weights)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_weights_are_refused_naming_the_tensor(tmp_path, bad):
    net = UNet(base_width=2, depth=2)
    victim = next(k for k, v in net.state_dict().items() if v.dtype == torch.float32 and v.numel() > 2)
    with torch.no_grad():
        net.state_dict()[victim].view(-1)[:2] = bad
    _save(tmp_path / "unet", net)
    with pytest.raises(ValueError, match=rf"tensor 'model\.{victim}' holds 2 non-finite value\(s\).*expected finite"):
        load_checkpoint(tmp_path / "unet.safetensors")
    with pytest.raises(ValueError, match="non-finite"):
        load_network(tmp_path / "unet.safetensors")
