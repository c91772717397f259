"""What notebooks 02 and 03 share: their parameters (:class:`HeldOutConfig`), the held-out hybrid
frames they evaluate on (:func:`held_out_frames`, split ``eval``) and the shipped checkpoints
(:func:`resolve_weights`, recorded by :func:`weights_part`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from histostudy.core import check_count, check_positive
from histostudy.imaging import BACKGROUNDS
from histostudy.learning import HybridFrames, RenderConfig, default_cache_dir, shipped_model

from .section import (
    SectionConfig,
    SectionPart,
    Timer,
    check_bool,
    check_choice,
    check_splat_device,
    check_text,
    timer_or_untimed,
)

__all__ = ["RECORDED_PARAMETERS", "HeldOutConfig", "held_out_frames", "network_description", "resolve_weights",
           "weights_part",
           "weights_summary", "prepare_held_out", "HeldOutSetup"]

#: The notebook parameters the reports of notebooks 02 and 03 record, in the order they record them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "splat_device", "render_spacing_mm",
                       "background", "n_eval_images", "weights")


@dataclass(frozen=True)
class HeldOutConfig(SectionConfig):
    """Notebooks 02 and 03's parameters, checked: :class:`histostudy.study.segmentation.SegmentationConfig`
    is these, :class:`histostudy.study.orientation.OrientationConfig` these and one of its own.

    Args:
        photons_per_pixel: unattenuated photons per detector pixel of the frames (dose, > 0).
        n_splats: splats per model point (>= 1).
        splat_sigma_mm: SD of each splat's jitter, mm (> 0).
        splat_device: where the frames are splatted, one of :data:`~histostudy.study.section.STUDY_SPLAT_DEVICES`.
        render_spacing_mm: grid spacing of the rendering and reference-label models, mm.
        background: the frames' scene, one of :data:`histostudy.imaging.BACKGROUNDS`.
        n_eval_images: held-out frames to evaluate (>= 1).
        weights: the checkpoint to evaluate (a path); ``""``: the shipped one.
        cache_frames: read the frames from (or render them into) the frame cache.
        render_workers: processes that pre-render the uncached frames (>= 1).

    Raises:
        ValueError: a bad value, naming the parameter, its value and what it must be.
    """

    photons_per_pixel: float
    n_splats: int
    splat_sigma_mm: float
    splat_device: str
    render_spacing_mm: float
    background: str
    n_eval_images: int
    weights: str | os.PathLike
    cache_frames: bool
    render_workers: int

    #: The notebook whose parameters cell names the fields (in :meth:`from_parameters`' message).
    NOTEBOOK = "02 or 03"
    RECORDED = RECORDED_PARAMETERS

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        for name, unit in (("photons_per_pixel", "photons per pixel"), ("splat_sigma_mm", "mm"),
                           ("render_spacing_mm", "mm")):
            put(name, check_positive(getattr(self, name), name, unit=unit))
        for name in ("n_splats", "n_eval_images", "render_workers"):
            put(name, check_count(getattr(self, name), name))
        check_choice(self.background, "background", BACKGROUNDS)
        check_splat_device(self.splat_device)
        if not isinstance(self.weights, os.PathLike):
            check_text(self.weights, "weights", "a checkpoint path or \"\" (the shipped network)")
        put("cache_frames", check_bool(self.cache_frames, "cache_frames"))



    def frames(self, seed: int, *, timer: Timer | None = None) -> HybridFrames:
        """:func:`held_out_frames` of ``seed`` on these parameters.

        Args:
            seed: the study seed.
            timer: ``timer(name)`` -> a context manager timing the pre-rendering; None: untimed.

        Returns:
            The held-out frames.
        """
        return held_out_frames(seed, self.n_eval_images, render_spacing_mm=self.render_spacing_mm,
                               photons_per_pixel=self.photons_per_pixel, n_splats=self.n_splats,
                               splat_sigma_mm=self.splat_sigma_mm, splat_device=self.splat_device,
                               background=self.background, cache_frames=self.cache_frames,
                               render_workers=self.render_workers, timer=timer)


def resolve_weights(weights: str | os.PathLike, shipped_name: str, network: str, train_task: str) -> Path:
    """The checkpoint to evaluate (notebooks 02 and 03 never train).

    Args:
        weights: a checkpoint path; ``""``: the shipped one.
        shipped_name: the shipped checkpoint's name in ``data/models`` (without suffix).
        network: the network's name, in the error message.
        train_task: the ``histostudy train`` task that makes the weights, in the error message.

    Returns:
        ``Path(weights)``, or the shipped checkpoint's path.

    Raises:
        FileNotFoundError: no ``weights`` and no usable shipped checkpoint.
    """
    path = Path(weights) if weights else shipped_model(shipped_name)
    if path is None:
        raise FileNotFoundError(f"no usable shipped {network} in data/models ({shipped_name}.safetensors + .json); "
                                f"train it with `histostudy train {train_task} --profile standard` "
                                f"or pass weights=<path>")
    return path


def held_out_frames(seed: int, n_images: int, *, render_spacing_mm: float, photons_per_pixel: float, n_splats: int,
                    splat_sigma_mm: float, background: str, splat_device: str = "numpy", cache_frames: bool = True,
                    render_workers: int = 1, timer: Timer | None = None) -> HybridFrames:
    """The evaluation split (``"eval"``) of the study's hybrid frames, which no training or
    validation frame shares a seed with (§II-B.2). The frames are the same cached or not.

    Args:
        seed: the study seed.
        n_images: the frames to pre-render (with ``render_workers`` > 1).
        render_spacing_mm: the images' and labels' model spacing, mm.
        photons_per_pixel: the dose, photons per detector pixel.
        n_splats: splats per model point.
        splat_sigma_mm: splat SD, mm.
        background: the scene, one of :data:`histostudy.imaging.BACKGROUNDS`.
        splat_device: where the frames are splatted (:data:`histostudy.imaging.SPLAT_DEVICES`); each
            renderer's frames are cached apart.
        cache_frames: read the frames from (or render them into) the frame cache.
        render_workers: with ``cache_frames``, processes that pre-render the first ``n_images``.
        timer: ``timer(name)`` -> a context manager timing the pre-rendering; None: untimed.

    Returns:
        A :class:`histostudy.learning.HybridFrames` (frame ``i`` is ``frames.frame(i)``).
    """
    render = RenderConfig(render_spacing_mm=render_spacing_mm, label_spacing_mm=render_spacing_mm,
                          photons_per_pixel=photons_per_pixel, n_splats=n_splats, splat_sigma_mm=splat_sigma_mm,
                          background=background, splat_device=splat_device)
    frames = HybridFrames("eval", seed, render, cache_dir=default_cache_dir() if cache_frames else None)
    if cache_frames and render_workers > 1:
        with timer_or_untimed(timer)(f"pre-render the uncached evaluation frames ({render_workers} processes)"):
            frames.prerender(n_images, workers=render_workers)
    return frames


def network_description(config: dict, *, named: bool = True) -> str:
    """A network's configuration in words, for a report (``"VGG19 at width 1/8, batch norms, (cos, sin)
    regressor"``, ``"U-Net, 8...128 channels over 4 levels"``); other keys as ``key value``.

    Args:
        config: the checkpoint's ``config`` (:func:`histostudy.learning.build_network`'s).
        named: start with the architecture's name (``"VGG19 at width 1/8"``); False: the rest only
            (``"width 1/8, batch norms, ..."``), for a caller that names the network itself.

    Returns:
        The description.
    """
    config = dict(config)
    arch = config.pop("arch", "network")
    config.pop("in_channels", None)
    config.pop("n_classes", None)
    name, words = str(arch), []
    if arch == "unet":
        name = "U-Net"
        base, depth = config.pop("base_width", None), config.pop("depth", None)
        if base is not None and depth is not None:
            words.append(f"{base}...{base * 2 ** depth} channels over {depth} levels")
        if config.pop("input_stride", 1) != 1:
            words.append("strided stem")
    elif arch == "vgg19":
        name = "VGG19"
        width = config.pop("width", 1.0)
        if width != 1:
            words.append(f"width 1/{round(1 / width)}")
        if config.pop("batch_norm", False):
            words.append("batch norms")
        head, encoding = config.pop("head", ""), config.pop("angle_encoding", "")
        if head:
            words.append(f"{'(cos, sin) ' if encoding == 'cos_sin' else ''}{head}")
    words += [f"{key} {value}" for key, value in sorted(config.items())]
    if not named:
        return ", ".join(words)
    if words and words[0].startswith("width "):  # "VGG19 at width 1/8, ..."
        name, words = f"{name} at {words[0]}", words[1:]
    return ", ".join([name, *words])


def weights_part(weights_path: Path, manifest: dict) -> SectionPart:
    """Which checkpoint the section evaluates: a short provenance table and the full record.

    Args:
        weights_path: the checkpoint.
        manifest: its manifest (the network's ``manifest``).

    Returns:
        A part with table ``network`` (the network in words, its file, SHA-256 prefix, profile,
        training steps, minutes and device) and value ``weights``: file, manifest, sha256,
        configuration, profile, training steps and validation.

    Raises:
        KeyError: the manifest lacks ``sha256`` or ``config``.
    """
    minutes = manifest.get("training_minutes")
    rows = [("network", network_description(manifest["config"])), ("weights", weights_path.name),
            ("SHA-256", manifest["sha256"][:12]), ("profile", manifest.get("profile") or "—"),
            ("training steps", manifest.get("training_steps") or "—"),
            ("training minutes", f"{minutes:.0f}" if isinstance(minutes, (int, float)) else "—"),
            ("trained on", manifest.get("device") or "—")]
    table = pd.DataFrame(rows, columns=["", "checkpoint"]).astype(str)
    return SectionPart(
        tables={"network": (table, "The network evaluated: its checkpoint and how it was trained (the manifest "
                                   "beside it holds the full record)")},
        values={"weights": {
            "file": str(weights_path), "manifest": str(weights_path.with_suffix(".json")),
            "sha256": manifest["sha256"], "config": manifest["config"], "profile": manifest.get("profile"),
            "training_steps": manifest.get("training_steps"), "validation": manifest.get("validation")}})


def weights_summary(network: str, weights_path: Path, manifest: dict, input_scale: float) -> str:
    """A one-line summary of the checkpoint for the notebook.

    Args:
        network: the network's name (``"U-Net"``, ``"VGG19"``).
        weights_path: the checkpoint.
        manifest: its manifest.
        input_scale: the network's input scale.

    Returns:
        The line.
    """
    described = network_description(manifest["config"], named=False)
    named = f"{network} ({described})" if described else network
    return (f"{named} from {weights_path.name}: {manifest.get('training_steps')} steps "
            f"(profile {manifest.get('profile')}), input scale {input_scale}")


@dataclass(frozen=True)
class HeldOutSetup:
    """What notebooks 02 and 03 run on; each notebook's set-up adds its network.

    Args:
        params: the checked parameters.
        seed: the study seed.
        weights_path: the network's checkpoint.
        frames: the held-out frames (:func:`held_out_frames`).
    """

    params: HeldOutConfig
    seed: int
    weights_path: Path
    frames: HybridFrames


def prepare_held_out(config_class, params, seed: int, load, *, timer: Timer | None = None) -> tuple:
    """What notebooks 02 and 03 set up alike.

    Args:
        config_class: the notebook's :class:`HeldOutConfig` subclass.
        params: a ``config_class``, or a mapping of its fields (checked into one).
        seed: the study seed.
        load: ``load(weights)`` -> ``(network, weights_path)``.
        timer: ``timer(name)`` -> a context manager timing the frames' pre-rendering; None: untimed.

    Returns:
        ``(params, seed, weights_path, frames, network)``, the order of a :class:`HeldOutSetup`
        subclass's fields.

    Raises:
        ValueError: a bad or missing parameter.
        FileNotFoundError: no usable checkpoint (from ``load``).
    """
    if not isinstance(params, config_class):
        params = config_class.from_parameters(params)
    network, weights_path = load(params.weights)
    return params, seed, weights_path, params.frames(seed, timer=timer), network
