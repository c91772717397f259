"""What notebooks 02 and 03 evaluate their shipped networks on: the parameters they share
(:class:`HeldOutConfig`, checked), the held-out hybrid frames (:func:`held_out_frames`: split ``eval``
of :class:`~histostudy.learning.HybridFrames`, which no training or validation frame shares a seed
with) and the shipped checkpoints (:func:`resolve_weights`, recorded by :func:`weights_part`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from histostudy.core import check_count, check_positive
from histostudy.imaging import BACKGROUNDS
from histostudy.learning import HybridFrames, RenderConfig, default_cache_dir, shipped_model

from .section import SectionConfig, SectionPart, Timer, check_bool, check_choice, check_text, timer_or_untimed

__all__ = ["RECORDED_PARAMETERS", "HeldOutConfig", "held_out_frames", "resolve_weights", "weights_part",
           "weights_summary", "prepare_held_out", "HeldOutSetup"]

#: The notebook parameters the reports of notebooks 02 and 03 record, in the order they record them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "render_spacing_mm", "background",
                       "n_eval_images", "weights")


@dataclass(frozen=True)
class HeldOutConfig(SectionConfig):
    """Notebooks 02 and 03's parameters, checked: the held-out frames' dose and splatting
    (``photons_per_pixel``, ``n_splats``, ``splat_sigma_mm`` in mm), their model grid
    (``render_spacing_mm``) and scene ``background`` (one of :data:`~histostudy.imaging.BACKGROUNDS`),
    how many to evaluate (``n_eval_images``), the network's ``weights`` (a path; ``""``: the shipped
    one), whether to cache the frames (``cache_frames``) and the processes that pre-render them
    (``render_workers``): :class:`~.segmentation.SegmentationConfig` (notebook 02) and
    :class:`~.orientation_regression.OrientationConfig` (notebook 03, with its own) are these.

    A bad value raises ValueError naming the parameter, its value and what it must be.
    """

    photons_per_pixel: float
    n_splats: int
    splat_sigma_mm: float
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
        if not isinstance(self.weights, os.PathLike):
            check_text(self.weights, "weights", "a checkpoint path or \"\" (the shipped network)")
        put("cache_frames", check_bool(self.cache_frames, "cache_frames"))



    def frames(self, seed: int, *, timer: Timer | None = None) -> HybridFrames:
        """:func:`held_out_frames` of ``seed`` on these parameters."""
        return held_out_frames(seed, self.n_eval_images, render_spacing_mm=self.render_spacing_mm,
                               photons_per_pixel=self.photons_per_pixel, n_splats=self.n_splats,
                               splat_sigma_mm=self.splat_sigma_mm, background=self.background,
                               cache_frames=self.cache_frames, render_workers=self.render_workers, timer=timer)


def resolve_weights(weights: str | os.PathLike, shipped_name: str, network: str, train_task: str) -> Path:
    """The checkpoint to evaluate: ``weights`` if given, else the shipped ``data/models/<shipped_name>``.

    Raises FileNotFoundError, naming the ``histostudy train <train_task>`` command that makes
    the weights, when neither is usable (notebooks 02 and 03 never train).
    """
    path = Path(weights) if weights else shipped_model(shipped_name)
    if path is None:
        raise FileNotFoundError(f"no usable shipped {network} in data/models ({shipped_name}.safetensors + .json); "
                                f"train it with `histostudy train {train_task} --profile standard` "
                                f"or pass weights=<path>")
    return path


def held_out_frames(seed: int, n_images: int, *, render_spacing_mm: float, photons_per_pixel: float, n_splats: int,
                    splat_sigma_mm: float, background: str, cache_frames: bool = True, render_workers: int = 1,
                    timer: Timer | None = None) -> HybridFrames:
    """The evaluation split (``"eval"``) of the study's hybrid frames, which no training or
    validation frame shares a seed with (§II-B.2; images and labels both from the
    ``render_spacing_mm`` models).

    With ``cache_frames`` the frames are read from (or rendered into) the frame cache, and with
    ``render_workers > 1`` the first ``n_images`` are pre-rendered in that many processes
    (``timer``, optional, times it). The frames are the same either way.
    """
    render = RenderConfig(render_spacing_mm=render_spacing_mm, label_spacing_mm=render_spacing_mm,
                          photons_per_pixel=photons_per_pixel, n_splats=n_splats, splat_sigma_mm=splat_sigma_mm,
                          background=background)
    frames = HybridFrames("eval", seed, render, cache_dir=default_cache_dir() if cache_frames else None)
    if cache_frames and render_workers > 1:
        with timer_or_untimed(timer)(f"pre-render the uncached evaluation frames ({render_workers} processes)"):
            frames.prerender(n_images, workers=render_workers)
    return frames


def weights_part(weights_path: Path, manifest: dict) -> SectionPart:
    """Which checkpoint the section evaluates (file, manifest, hash, configuration, training
    record), as value ``weights``."""
    return SectionPart(values={"weights": {
        "file": str(weights_path), "manifest": str(weights_path.with_suffix(".json")), "sha256": manifest["sha256"],
        "config": manifest["config"], "profile": manifest.get("profile"),
        "training_steps": manifest.get("training_steps"), "validation": manifest.get("validation")}})


def weights_summary(network: str, weights_path: Path, manifest: dict, input_scale: float) -> str:
    """A one-line summary of the checkpoint for the notebook."""
    return (f"{network} {manifest['config']} from {weights_path.name}: {manifest.get('training_steps')} steps "
            f"(profile {manifest.get('profile')}), input scale {input_scale}")


@dataclass(frozen=True)
class HeldOutSetup:
    """What notebooks 02 and 03 run on: their checked ``params``, the ``seed``, the network's
    ``weights_path`` and the held-out ``frames`` (:func:`held_out_frames`); each notebook's set-up
    adds its network."""

    params: HeldOutConfig
    seed: int
    weights_path: Path
    frames: HybridFrames


def prepare_held_out(config_class, params, seed: int, load, *, timer: Timer | None = None) -> tuple:
    """What notebooks 02 and 03 set up alike: ``params`` checked into ``config_class`` (a
    :class:`HeldOutConfig`, or a mapping of its fields), the network ``load(params.weights)`` gives
    with its weights path, and the held-out frames of ``seed`` (``timer`` times their pre-rendering);
    returned in the order of a :class:`HeldOutSetup` subclass's fields, ``(params, seed,
    weights_path, frames, network)``."""
    if not isinstance(params, config_class):
        params = config_class.from_parameters(params)
    network, weights_path = load(params.weights)
    return params, seed, weights_path, params.frames(seed, timer=timer), network
