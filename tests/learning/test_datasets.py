"""Hybrid-image datasets: input transforms, seeds per split, poses, angles under flips, the cache."""

import numpy as np
import pytest
import torch

from histostudy.core import stage_delta, stage_totals
from histostudy.geometry import check_rigid
from histostudy.imaging import View
from histostudy.learning import HybridFrames, RenderConfig, angles_from_direction, beam_direction_of_pose, pool_labels
from histostudy.learning.datasets import (
    SPLIT_CODES,
    HybridImageDataset,
    flip_angles,
    random_training_pose,
    true_angles,
)
from histostudy.learning.orientation import hemisphere_directions
from histostudy.learning.preprocess import prepare_image
from histostudy.transducer import Feature

# small detector and coarse model: frames in well under a second
TINY = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320))


def test_prepare_image_is_area_mean_then_standardised():
    rng = np.random.default_rng(0)
    img = rng.normal(3.0, 2.0, (8, 12)).astype(np.float32)
    out = prepare_image(img, 0.5)
    block = img.reshape(4, 2, 6, 2).mean(axis=(1, 3))
    expected = (block - block.mean()) / block.std()
    np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-5)
    assert out.dtype == np.float32 and abs(out.mean()) < 1e-6 and out.std() == pytest.approx(1, rel=1e-5)
    with pytest.raises(ValueError, match="not divisible"):
        prepare_image(np.zeros((9, 12)), 0.5)
    with pytest.raises(ValueError, match="1/k"):
        prepare_image(img, 0.3)
    with pytest.raises(ValueError, match="2-D numeric"):
        prepare_image(np.zeros((2, 4, 4)), 0.5)


def test_pool_labels_keeps_the_highest_priority_class():
    lab = np.array([[0, 1, 4, 1],
                    [3, 2, 5, 4],
                    [0, 0, 2, 1],
                    [0, 0, 1, 1]], np.uint8)
    # blocks: {0,1,3,2} -> inner (3) beats outer (2) and elements; {4,1,5,4} -> screws;
    # {0,0,0,0} -> background; {2,1,1,1} -> outer boundary
    np.testing.assert_array_equal(pool_labels(lab, 0.5), [[Feature.INNER_BOUNDARY, Feature.SCREWS],
                                                          [Feature.BACKGROUND, Feature.OUTER_BOUNDARY]])
    np.testing.assert_array_equal(pool_labels(lab, 1.0), lab)


def test_random_pose_is_rigid_and_on_the_detector():
    view = View.from_gantry(30.0, shape=(240, 320))
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = check_rigid(random_training_pose(rng, view))
        assert np.all(np.abs(T[:3, 3]) <= 100.0)
        u, v = view.project((T[:3, 3] + 138.7 * T[:3, 2])[None])[0]
        assert 0 <= u < 320 and 0 <= v < 240


def test_splits_never_share_seeds_and_frames_are_reproducible():
    seqs = {(split, i): HybridFrames(split, 5, TINY).seed_sequence(i).entropy
            for split in SPLIT_CODES for i in range(4)}
    assert len(set(map(tuple, seqs.values()))) == len(seqs)
    a, b = HybridFrames("train", 5, TINY).frame(0), HybridFrames("train", 5, TINY).frame(0)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.labels, b.labels)
    c = HybridFrames("eval", 5, TINY).frame(0)
    assert not np.array_equal(a.T_carm_transducer, c.T_carm_transducer)
    with pytest.raises(ValueError, match="split"):
        HybridFrames("test", 5, TINY)


def test_flip_angles_match_the_mirrored_direction():
    view = View.from_gantry(20.0)
    rng = np.random.default_rng(4)
    for _ in range(10):
        d = rng.normal(size=3)
        az, el = angles_from_direction(d, view)
        d_det = view.detector_axes @ d
        for flip_cols, flip_rows in ((True, False), (False, True), (True, True)):
            m = d_det * [-1 if flip_cols else 1, -1 if flip_rows else 1, 1]
            az_m, el_m = angles_from_direction(view.detector_axes.T @ m, view)
            assert np.cos(flip_angles(az, flip_cols, flip_rows) - az_m) == pytest.approx(1.0, abs=1e-12)
            assert el_m == pytest.approx(el)


def test_segmentation_items():
    frames = HybridFrames("train", 1, TINY)
    ds = HybridImageDataset("segmentation", frames, 3, scale=0.5, crop=64, seed=1)
    item = ds[0]
    assert item["image"].shape == (1, 64, 64) and item["image"].dtype == torch.float32
    assert item["labels"].shape == (64, 64) and item["labels"].dtype == torch.int64
    full = HybridImageDataset("segmentation", frames, 3, scale=0.5, seed=1)[0]
    assert full["image"].shape == (1, 120, 160)
    np.testing.assert_array_equal(full["labels"].numpy(), pool_labels(frames.frame(0).labels, 0.5))
    ds.set_epoch(1)
    assert not torch.equal(ds[0]["image"], item["image"])  # a new crop each epoch
    with pytest.raises(IndexError):
        ds[3]
    with pytest.raises(ValueError, match="crop"):
        HybridImageDataset("segmentation", frames, 3, scale=0.5, crop=500)


def test_orientation_items_angles_classes_and_flips(tmp_path):
    frames = HybridFrames("train", 2, TINY, cache_dir=tmp_path)
    plain = HybridImageDataset("orientation", frames, 4, scale=0.25)
    aug = HybridImageDataset("orientation", frames, 4, scale=0.25, augment=True, seed=9)
    dirs = hemisphere_directions()
    flipped = 0
    for i in range(4):
        p, a = plain[i], aug[i]
        frame = frames.frame(i)
        assert frame.meta["cached"]
        az, el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        np.testing.assert_allclose(p["angles"].numpy(), [az, el], atol=1e-6)
        d = np.array([np.cos(az) * np.sin(el), np.sin(az) * np.sin(el), -np.cos(el)])
        assert int(p["class"]) == int(np.argmin(np.arccos(np.clip(dirs @ d, -1, 1))))
        img, aimg = p["image"][0].numpy(), a["image"][0].numpy()
        for fc in (False, True):
            for fr in (False, True):
                candidate = img[::-1 if fr else 1, ::-1 if fc else 1]
                if np.array_equal(candidate, aimg):
                    assert np.cos(float(a["angles"][0]) - flip_angles(az, fc, fr)) == pytest.approx(1.0, abs=1e-6)
                    flipped += fc or fr
    assert flipped >= 1


def test_cache_reads_back_what_was_rendered(tmp_path):
    cached = HybridFrames("val", 3, TINY, cache_dir=tmp_path)
    first = cached.frame(1)
    files = list(tmp_path.rglob("*.npz"))
    assert len(files) == 1
    again = cached.frame(1)
    assert again.meta["cached"] and not first.meta["cached"]
    np.testing.assert_array_equal(first.image, again.image)
    np.testing.assert_array_equal(first.labels, again.labels)
    uncached = HybridFrames("val", 3, TINY).frame(1)
    np.testing.assert_allclose(again.image, uncached.image, atol=0.01)  # float16 storage
    assert true_angles(again) == pytest.approx(true_angles(uncached))
    files[0].write_bytes(b"damaged")
    np.testing.assert_array_equal(cached.frame(1).image, first.image)  # rendered again


def test_prerender_fills_the_cache_with_the_frames_the_loop_would_render(tmp_path):
    from histostudy.learning import HybridFrames

    cfg = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(120, 160))
    frames = HybridFrames("val", 8, cfg, cache_dir=tmp_path)
    before = stage_totals()
    assert frames.prerender(3, workers=2) == 3
    assert stage_delta(before)["render"]["calls"] == 3  # the workers' renders, added to this process's
    assert all(frames.cached(i) for i in range(3)) and not frames.cached(3)
    assert frames.prerender(4, workers=2) == 1  # only what is missing
    assert stage_delta(before)["render"]["calls"] == 4  # that one here
    uncached = HybridFrames("val", 8, cfg)
    for i in (0, 3):
        cached, fresh = frames.frame(i), uncached.frame(i)
        assert cached.meta["cached"]
        np.testing.assert_array_equal(cached.image, fresh.image.astype(np.float16).astype(np.float32))
        np.testing.assert_array_equal(cached.labels, fresh.labels)
    with pytest.raises(ValueError, match="cache_dir"):
        uncached.prerender(2)
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        frames.prerender(2, workers=0)
    with pytest.raises(ValueError, match="n must be"):
        frames.prerender(-1)


def test_kept_inputs_give_the_same_items_without_reading_the_frame_again(tmp_path, monkeypatch):
    cfg = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(120, 160))
    frames = HybridFrames("train", 9, cfg, cache_dir=tmp_path)
    for task, kw in (("orientation", dict(scale=0.25, augment=True)), ("segmentation", dict(scale=0.5, crop=16))):
        plain = HybridImageDataset(task, frames, 2, seed=9, **kw)
        kept = HybridImageDataset(task, frames, 2, seed=9, keep_in_memory=True, **kw)
        first = [kept[i] for i in range(2)]
        calls = []
        real_frame = HybridFrames.frame
        monkeypatch.setattr(HybridFrames, "frame",
                            lambda self, i, calls=calls, real_frame=real_frame: calls.append(i) or real_frame(self, i))
        for epoch in (0, 1, 2):
            plain.set_epoch(epoch)
            kept.set_epoch(epoch)
            for i in range(2):
                a, b = plain[i], kept[i]
                assert a.keys() == b.keys()
                for key in a:
                    torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
        assert calls == [0, 1] * 3  # only the plain dataset read the frames again
        monkeypatch.undo()
        kept.set_epoch(0)
        b = kept[0]["image"]
        b += 1.0  # an item is the caller's to change: the kept input stays as it was
        torch.testing.assert_close(kept[0]["image"], first[0]["image"], rtol=0, atol=0)


def test_render_config_shares_the_render_settings_and_keeps_its_cache_key():
    from histostudy.imaging import FrameRenderConfig

    cfg = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320))
    assert isinstance(cfg, FrameRenderConfig) and cfg.background == "mixed"  # the paper's training mix
    assert cfg.frame_kwargs() == FrameRenderConfig().frame_kwargs()
    # the cache folder's name (frames-<key>) predates FrameRenderConfig: existing caches stay valid
    assert RenderConfig().key() == "0bdcc2e82d45" and cfg.key() == "cce851b71071"
    with pytest.raises(ValueError, match="n_splats"):
        RenderConfig(n_splats=0)
    with pytest.raises(ValueError, match="background"):
        RenderConfig(background="none")


def test_a_splat_device_renders_the_frames_elsewhere_in_a_cache_of_its_own(tmp_path):
    cfg = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(120, 160))
    compiled = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(120, 160), splat_device="cpu")
    # the reference keeps its key; another renderer's frames (another draw of the jitter) get their own
    assert RenderConfig().key() == "0bdcc2e82d45" and RenderConfig(splat_device="cpu").key() != RenderConfig().key()
    auto = HybridFrames("val", 2, RenderConfig(splat_device="auto"))
    assert auto.config.splat_device == ("cuda" if torch.cuda.is_available() else "cpu")
    assert auto.config.key() == RenderConfig(splat_device=auto.config.splat_device).key()

    frames = HybridFrames("val", 2, compiled, cache_dir=tmp_path)
    reference = HybridFrames("val", 2, cfg, cache_dir=tmp_path)
    assert frames.prerender(2, workers=2) == 2
    assert not reference.cached(0)
    a, b = frames.frame(1), reference.frame(1)
    np.testing.assert_array_equal(a.labels, b.labels)          # same pose and view, same labels
    np.testing.assert_array_equal(a.T_carm_transducer, b.T_carm_transducer)
    assert not np.array_equal(a.image, b.image)                 # another draw of the splat jitter
    assert abs(float(a.image.mean()) - float(b.image.mean())) < 0.01 * float(b.image.mean()) + 0.01
    with pytest.raises(ValueError, match="splat_device must be one of"):
        RenderConfig(splat_device="gpu")
