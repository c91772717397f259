"""Hybrid training and evaluation images for the learned stages (paper §II-B.2, §II-B.4): a procedural
background plus the rendered physical transducer at a random pose, seeded per split and frame, optionally
cached on disk (docs/training.md, "The hybrid images").
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, replace
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from histostudy.core import (
    atomic_path,
    check_count,
    check_positive,
    check_unit_fraction,
    merge_stage_totals,
    stage,
    stage_delta,
    stage_totals,
)
from histostudy.geometry import make_transform, matrix_from_euler
from histostudy.imaging import FrameRenderConfig, View, random_background, render_frame
from histostudy.transducer import TransducerModel

from .orientation import angles_from_direction, beam_direction_of_pose, orientation_class, wrap_angle
from .preprocess import pool_labels, prepare_image

__all__ = [
    "SPLIT_CODES",
    "HybridFrames",
    "HybridImageDataset",
    "RenderConfig",
    "default_cache_dir",
    "flip_angles",
    "random_training_pose",
    "true_angles",
]

#: Seed-sequence codes of the splits; distinct codes keep the splits' seeds disjoint.
SPLIT_CODES = {"train": 1, "val": 2, "eval": 3}

TASKS = ("segmentation", "orientation")


# --- frames ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class RenderConfig(FrameRenderConfig):
    """How hybrid frames are made (defaults: the paper's rendering, §II-B.2).

    The dose, splatting and scene are the shared :class:`~histostudy.imaging.FrameRenderConfig`
    (its checks included), here with the paper's ``"mixed"`` training backgrounds (156 abdomen :
    56 phantom images); ``"none"`` is not a training background.

    Attributes:
        render_spacing_mm: grid spacing of the physical model that makes the image (0.125 mm).
        label_spacing_mm: grid spacing of the digital model that makes the reference labels.
        physical_seed: seed of the one physical transducer (manufacturing deviation) of the study.
        translation_range_mm: focal-point translation range per axis (100 mm = 10 cm).
        primary_range_deg: range of the views' primary (LAO/RAO) angle, uniform.
        detector: ``(rows, cols)`` of the full-resolution detector.

    Raises:
        ValueError: a field is out of its range (the message names it).
    """

    background: str = "mixed"
    render_spacing_mm: float = 0.125
    label_spacing_mm: float = 0.125
    physical_seed: int = 0
    translation_range_mm: float = 100.0
    primary_range_deg: tuple = (-90.0, 90.0)
    detector: tuple = (960, 1240)

    def __post_init__(self):
        super().__post_init__()
        if self.photons_per_pixel is None:
            raise ValueError("photons_per_pixel must be a finite number > 0 for hybrid frames, got None")
        for name in ("render_spacing_mm", "label_spacing_mm", "translation_range_mm"):
            check_positive(getattr(self, name), name)
        if self.background == "none":
            raise ValueError(f"background must be 'abdomen', 'phantom' or 'mixed', got {self.background!r}")
        lo, hi = (float(v) for v in self.primary_range_deg)
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise ValueError(f"primary_range_deg must be (low, high) degrees with low <= high, "
                             f"got {self.primary_range_deg!r}")
        object.__setattr__(self, "primary_range_deg", (lo, hi))
        object.__setattr__(self, "detector", tuple(int(v) for v in self.detector))

    def resolved(self) -> RenderConfig:
        """This configuration with ``splat_device="auto"`` replaced by the device it means here."""
        if self.splat_device != "auto":
            return self
        return replace(self, splat_device=self.resolved_device())

    def key(self) -> str:
        """A short hash of the configuration (names the cache folder); the reference renderer's
        key leaves ``splat_device`` out, so caches made before the field existed stay valid."""
        fields_ = asdict(self.resolved())
        if fields_["splat_device"] is None:
            del fields_["splat_device"]
        return hashlib.sha256(json.dumps(fields_, sort_keys=True).encode()).hexdigest()[:12]


@lru_cache(maxsize=4)
def _models(render_spacing_mm: float, label_spacing_mm: float, physical_seed: int):
    physical = TransducerModel.build_physical(spacing_mm=render_spacing_mm,
                                              rng=np.random.default_rng(physical_seed))
    digital = TransducerModel.build(spacing_mm=label_spacing_mm)
    return digital, physical


def random_training_pose(rng: np.random.Generator, view: View, translation_range_mm: float = 100.0,
                         max_tries: int = 1000) -> np.ndarray:
    """A §II-B.2 random pose ``T_carm_transducer`` whose transducer centre projects onto ``view``.

    Euler angles (extrinsic ``xyz``) uniform in ``[0, 2 pi)`` and a translation of the focal point
    uniform in ``[-translation_range_mm, translation_range_mm]`` per axis, redrawn (up to
    ``max_tries``) until the transducer centre — ``R`` (the cap radius) along the transducer's +z
    from the focal point — falls on the detector.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    radius = 138.7
    rows, cols = view.shape
    for _ in range(max_tries):
        R = matrix_from_euler(rng.uniform(0.0, 2 * np.pi, size=3), "xyz")
        t = rng.uniform(-translation_range_mm, translation_range_mm, size=3)
        centre = t + radius * R[:, 2]
        u, v = view.project(centre[None])[0]
        if 0 <= u < cols and 0 <= v < rows:
            return make_transform(R, t)
    raise RuntimeError(f"no pose with the transducer centre on view {view.name!r} in {max_tries} draws")


class HybridFrames:
    """Frame ``i`` of a split: full-resolution hybrid image, labels, pose and view (docs/training.md).

    Args:
        split: ``"train"``, ``"val"`` or ``"eval"``.
        seed: the study seed.
        config: a :class:`RenderConfig`.
        cache_dir: folder for rendered frames (None: render every time).

    Raises:
        ValueError: ``split`` is not one of :data:`SPLIT_CODES`.
        TypeError: ``config`` is not a :class:`RenderConfig`.
    """

    def __init__(self, split: str, seed: int, config: RenderConfig | None = None, cache_dir=None):
        if split not in SPLIT_CODES:
            raise ValueError(f"split must be one of {sorted(SPLIT_CODES)}, got {split!r}")
        check_count(seed, "seed", minimum=0)
        self.split, self.seed = split, int(seed)
        config = RenderConfig() if config is None else config
        if not isinstance(config, RenderConfig):
            raise TypeError(f"config must be a RenderConfig, got {type(config).__name__}")
        self.config = config.resolved()
        self.cache_dir = None if cache_dir is None else Path(cache_dir) / f"frames-{self.config.key()}"

    def seed_sequence(self, index: int) -> np.random.SeedSequence:
        """The seed sequence of frame ``index`` (distinct for every split, seed and index)."""
        check_count(index, "index", minimum=0)
        return np.random.SeedSequence([self.seed, SPLIT_CODES[self.split], int(index)])

    def view(self, index: int) -> View:
        """The view of frame ``index`` (primary angle drawn from the frame's own seed)."""
        rng = np.random.default_rng(self.seed_sequence(index).spawn(1)[0])
        lo, hi = self.config.primary_range_deg
        return View.from_gantry(float(rng.uniform(lo, hi)), 0.0, shape=self.config.detector,
                                name=f"{self.split}{index}")

    def cached(self, index: int) -> bool:
        """Whether frame ``index`` is in the on-disk cache."""
        return self.cache_dir is not None and self._cache_path(index).is_file()

    def _cache_path(self, index: int) -> Path:
        if self.cache_dir is None:
            raise ValueError("these frames have no cache_dir: there is no cache path")
        return self.cache_dir / f"{self.split}-{self.seed}-{int(index):06d}.npz"

    def prerender(self, n: int, workers: int = 1) -> int:
        """Render the frames ``0`` to ``n - 1`` that the cache lacks, in ``workers`` processes; returns how many.

        The frames are the ones :meth:`frame` renders (each from its own seed), so a training
        run that finds them cached computes exactly what it would have computed rendering them
        itself; only the wall time differs. Needs a cache folder. The worker processes' render
        time is added to this process's stage times (:func:`histostudy.core.merge_stage_totals`).
        """
        if self.cache_dir is None:
            raise ValueError("prerender needs a cache_dir: without one the rendered frames would be thrown away")
        check_count(n, "n", minimum=0)
        check_count(workers, "workers")
        missing = [i for i in range(int(n)) if not self.cached(i)]
        if workers == 1 or len(missing) < 2:
            for i in missing:
                self.frame(i)
            return len(missing)
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawned, not forked: a fork of a process whose torch/OpenMP pools are running can hang
        with ProcessPoolExecutor(max_workers=int(workers), mp_context=multiprocessing.get_context("spawn"),
                                 initializer=_single_threaded_worker) as pool:
            for stages in pool.map(_render_into_cache, [self] * len(missing), missing, chunksize=4):
                merge_stage_totals(stages)
        return len(missing)

    @stage("render")  # a frame read back from the cache is a render-stage cost too
    def frame(self, index: int):
        """The :class:`~histostudy.imaging.frame.Frame` of ``index`` (rendered, or read from the cache)."""
        from histostudy.imaging import Frame

        view = self.view(index)
        path = None if self.cache_dir is None else self._cache_path(index)
        if path is not None and path.is_file():
            try:
                with np.load(path, allow_pickle=False) as data:
                    return Frame(image=data["image"].astype(np.float32), view=view, labels=data["labels"],
                                 T_carm_transducer=data["T"],
                                 meta={"split": self.split, "index": int(index), "cached": True})
            except (OSError, ValueError, KeyError):
                path.unlink(missing_ok=True)  # a damaged cache entry is rendered again
        cfg = self.config
        rng = np.random.default_rng(self.seed_sequence(index).spawn(2)[1])
        T = random_training_pose(rng, view, cfg.translation_range_mm)
        anatomy = random_background(rng, cfg.background)
        digital, physical = _models(cfg.render_spacing_mm, cfg.label_spacing_mm, cfg.physical_seed)
        frame = render_frame(digital, T, view, rng=rng, physical=physical, background=anatomy,
                             **cfg.frame_kwargs())
        if path is not None:
            with atomic_path(path) as tmp:
                np.savez(tmp, image=frame.image.astype(np.float16), labels=frame.labels, T=frame.T_carm_transducer)
            # the same numbers whether this frame was just rendered or read back from the cache
            frame = Frame(image=frame.image.astype(np.float16).astype(np.float32), view=view, labels=frame.labels,
                          T_carm_transducer=frame.T_carm_transducer,
                          meta={"split": self.split, "index": int(index), "cached": False})
        return frame


def _single_threaded_worker() -> None:
    """One thread per pre-rendering process: the processes are the parallelism."""
    import numba

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    numba.set_num_threads(1)


def _render_into_cache(frames: HybridFrames, index: int) -> dict:
    """Frame ``index`` rendered into the cache in a worker process; the stage times it charged
    there, which the parent adds to its own."""
    before = stage_totals()
    frames.frame(index)
    return stage_delta(before)


def true_angles(frame) -> tuple[float, float]:
    """``(azimuth_rad, elevation_rad)`` of a synthetic frame's true pose relative to its view."""
    return angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)


def flip_angles(azimuth_rad: float, flip_cols: bool, flip_rows: bool) -> float:
    """Azimuth of the mirrored image: a column flip maps ``az -> pi - az``, a row flip ``az -> -az``.

    With the principal point at the detector centre an image flip is exactly the projection of the
    mirrored scene; the transducer's mirror image is the transducer (its features are symmetric
    about the x and y planes), and the elevation does not change.
    """
    az = float(azimuth_rad)
    if flip_cols:
        az = np.pi - az
    if flip_rows:
        az = -az
    return float(wrap_angle(az))


class HybridImageDataset(Dataset):
    """A torch ``Dataset`` of network-ready hybrid images (a map-style dataset of ``size`` frames).

    Args:
        task: ``"segmentation"`` -> ``{"image": (1, h, w) float32, "labels": (h, w) int64}``;
            ``"orientation"`` -> ``{"image": (1, h, w), "angles": (2,) float32 rad (azimuth,
            elevation), "class": int64 (nearest of the 36 hemisphere orientations)}``.
        frames: the :class:`HybridFrames` of a split.
        size: number of frames (indices ``0 .. size-1``).
        scale: input downscale (0.5 for the U-Net here, 0.25 for the VGG as in §II-B.4).
        crop: square crop size in network pixels (segmentation training; None: the whole image).
        augment: random image flips with the exactly mirrored angles (orientation training).
        seed: seeds the crops and flips with :meth:`set_epoch`, so each epoch sees new ones.
        repeats: items per frame: item ``i`` is frame ``i // repeats`` with its own crop and flips,
            so one epoch takes ``repeats`` different crops of every frame (``len = size * repeats``).
        keep_in_memory: keep each frame's network input (downscaled, standardised) and targets
            after its first use, so that later epochs skip reading and downscaling the
            full-resolution frame (a third of a CPU orientation step); the items are the same.
            3000 orientation inputs at 310x240 take 0.9 GB.
        target_labels: segmentation only: a callable from the whole network input ``(h, w)`` to
            its labels on the same grid (a teacher network's, docs/training.md), used instead of
            the frame's pooled labels; kept with the input when ``keep_in_memory``.
    """

    def __init__(self, task: str, frames: HybridFrames, size: int, *, scale: float, crop: int | None = None,
                 augment: bool = False, seed: int = 0, repeats: int = 1, keep_in_memory: bool = False,
                 target_labels=None):
        if task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {task!r}")
        if not isinstance(frames, HybridFrames):
            raise TypeError(f"frames must be HybridFrames, got {type(frames).__name__}")
        check_count(size, "size")
        check_unit_fraction(scale)
        rows, cols = (s * scale for s in frames.config.detector)
        if crop is not None and (isinstance(crop, bool) or not isinstance(crop, int)
                                 or not 1 <= crop <= min(rows, cols)):
            raise ValueError(f"crop must be None or an integer in [1, {int(min(rows, cols))}] px, got {crop!r}")
        check_count(repeats, "repeats")
        self.task, self.frames, self.size, self.scale, self.crop = task, frames, size, float(scale), crop
        self.repeats = repeats
        self.augment, self.seed, self.epoch = bool(augment), int(seed), 0
        self._kept: dict | None = {} if keep_in_memory else None
        if target_labels is not None and (task != "segmentation" or not callable(target_labels)):
            raise ValueError(f"target_labels must be None or a callable (network input -> labels) for a "
                             f"segmentation dataset, got {target_labels!r} for task {task!r}")
        self.target_labels = target_labels

    def _prepared(self, frame_index: int):
        """The frame's network input and target: pooled labels (segmentation) or true angles."""
        if self._kept is not None and frame_index in self._kept:
            return self._kept[frame_index]
        frame = self.frames.frame(frame_index)
        image = prepare_image(frame.image, self.scale)
        target: tuple[float, float] | np.ndarray
        if self.task != "segmentation":
            target = true_angles(frame)
        elif self.target_labels is not None:
            target = np.asarray(self.target_labels(image))
            if target.shape != image.shape:
                raise ValueError(f"target_labels gave labels of shape {target.shape} for an input of shape "
                                 f"{image.shape}; expected the same grid")
        else:
            target = pool_labels(frame.labels, self.scale)
        if self._kept is not None:
            image.setflags(write=False)  # crops and flips are views: the kept input must not change
            self._kept[frame_index] = (image, target)
        return image, target

    def set_epoch(self, epoch: int) -> None:
        """Draw new crops and flips for ``epoch``."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.size * self.repeats

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for a dataset of {len(self)} items")
        image, target = self._prepared(index // self.repeats)
        rng = np.random.default_rng([self.seed, SPLIT_CODES[self.frames.split], index, self.epoch])
        if self.task == "segmentation":
            labels = target
            if self.crop is not None:
                r0 = int(rng.integers(0, image.shape[0] - self.crop + 1))
                c0 = int(rng.integers(0, image.shape[1] - self.crop + 1))
                image = image[r0:r0 + self.crop, c0:c0 + self.crop]
                labels = labels[r0:r0 + self.crop, c0:c0 + self.crop]
            return {"image": torch.from_numpy(image.copy())[None],
                    "labels": torch.from_numpy(labels.astype(np.int64))}
        az, el = target
        if self.augment:
            flip_cols, flip_rows = bool(rng.integers(2)), bool(rng.integers(2))
            if flip_cols:
                image = image[:, ::-1]
            if flip_rows:
                image = image[::-1]
            az = flip_angles(az, flip_cols, flip_rows)
        cls = orientation_class(az, el)
        return {"image": torch.from_numpy(image.copy())[None],
                "angles": torch.tensor([az, el], dtype=torch.float32),
                "class": torch.tensor(cls, dtype=torch.int64)}


def default_cache_dir() -> Path:
    """Where rendered frames and training runs are kept.

    Returns:
        ``$HISTOSTUDY_CACHE``, or ``~/.cache/histostudy`` where it is not set (not created here).
    """
    return Path(os.environ.get("HISTOSTUDY_CACHE", Path.home() / ".cache" / "histostudy"))
