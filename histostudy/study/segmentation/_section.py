"""Notebook 02's section (§II-B.2, §II-E.1, §III): the U-Net on the held-out hybrid frames, scored
pixel by pixel against the reference labels; Table I, the per-image summary, and the ANOVA and Tukey
HSD of the classes' precision, each heading's part a :class:`~histostudy.study.section.SectionPart`
(docs/study-sections.md, "02").
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.learning import HybridFrames, UNetRunner, training_summary
from histostudy.transducer import Feature

from ..held_out import HeldOutConfig, HeldOutSetup, network_description, prepare_held_out, resolve_weights
from ..section import SectionPart, Timer, timer_or_untimed
from ..stats import anova_oneway, segmentation_metrics, tukey_hsd

SECTION = "02_segmentation"
TITLE = "02 · Feature segmentation with the U-Net: Table I, ANOVA and Tukey HSD (§II-B.2, §II-E.1, §III)"

#: Row names of Table I, in label order (also the paper-value keys ``table1.<class>.<metric>``).
CLASS_KEYS = tuple(f.name.lower() for f in Feature)

#: Table I's per-class metrics, in percent.
METRICS = ("precision", "recall", "iou", "accuracy")

#: Paper-value keys of the per-image summary metrics, in report order.
SUMMARY_KEYS = {"global_accuracy": "seg.global_accuracy", "weighted_iou": "seg.weighted_iou",
                "mean_precision": "seg.mean_precision", "mean_recall": "seg.mean_recall"}


@dataclass(frozen=True)
class SegmentationConfig(HeldOutConfig):
    """Notebook 02's parameters, checked (the fields of :class:`histostudy.study.held_out.HeldOutConfig`);
    built from the parameters cell by ``SegmentationConfig.from_parameters(globals())``.

    Args:
        photons_per_pixel: unattenuated photons per detector pixel of the frames (dose, > 0).
        n_splats: splats per model point (>= 1).
        splat_sigma_mm: SD of each splat's jitter, mm (> 0).
        render_spacing_mm: grid spacing of the rendering and reference-label models, mm.
        background: the frames' scene, one of :data:`histostudy.imaging.BACKGROUNDS`.
        n_eval_images: held-out frames to evaluate (>= 1).
        weights: the checkpoint to evaluate (a path); ``""``: the shipped one.
        cache_frames: read the frames from (or render them into) the frame cache.
        render_workers: processes that pre-render the uncached frames (>= 1; needs ``cache_frames``).

    Raises:
        ValueError: a bad value, naming the parameter, its value and what it must be (or, from
            ``from_parameters``, the parameters the mapping lacks).
    """

    NOTEBOOK = "02"


def load_unet(weights: str | os.PathLike = "") -> tuple[UNetRunner, Path]:
    """The U-Net to evaluate and its checkpoint path.

    Args:
        weights: a checkpoint path; ``""``: the shipped ``data/models/unet_standard.safetensors``.

    Returns:
        ``(segmenter, path)``.

    Raises:
        FileNotFoundError: no ``weights`` given and no usable shipped U-Net (names the
            ``histostudy train segmentation`` command that makes it).
    """
    path = resolve_weights(weights, "unet_standard", "U-Net", "segmentation")
    return UNetRunner.load(path), path


def evaluate_segmentation(segmenter, frames: Iterable, rng: np.random.Generator | None = None, *,
                          keep: int = 3) -> tuple[pd.DataFrame, pd.DataFrame, list]:
    """Segment ``frames`` and measure each against its reference labels, pixel by pixel (§II-E.1).

    Args:
        segmenter: anything with ``segment(frame, rng)`` returning a label image (e.g.
            :class:`histostudy.learning.UNetRunner`).
        frames: frames with reference labels (any iterable; a generator keeps memory flat).
        rng: passed to ``segmenter.segment`` (None for a deterministic segmenter).
        keep: how many of the first frames' predictions to return (for figures).

    Returns:
        ``(per_class, per_image, predictions)``: ``per_class`` one row per image and class
        (``image, class, precision, recall, iou, accuracy`` in percent, NaN where undefined, plus
        the confusion counts), ``per_image`` one row per image (``global_accuracy, weighted_iou,
        mean_precision, mean_recall`` in percent, ``seconds`` of segmentation), ``predictions`` the
        label images of the first ``keep`` frames.

    Raises:
        ValueError: a frame without reference labels, or no frame at all.
    """
    rows, images, predictions = [], [], []
    for i, frame in enumerate(frames):
        if frame.labels is None:
            raise ValueError(f"frame {i} (view {frame.view.name!r}) has no reference labels to evaluate against")
        t0 = time.perf_counter()
        pred = segmenter.segment(frame, rng)
        seconds = time.perf_counter() - t0
        m = segmentation_metrics(pred, frame.labels, len(Feature), class_names=CLASS_KEYS)
        t = m["per_class"].copy()
        t[list(METRICS)] *= 100.0
        t.insert(0, "image", i)
        rows.append(t)
        images.append({"image": i, "global_accuracy": 100.0 * m["global_accuracy"],
                       "weighted_iou": 100.0 * m["weighted_iou"],
                       "mean_precision": float(np.nanmean(t["precision"])),
                       "mean_recall": float(np.nanmean(t["recall"])), "seconds": seconds})
        if i < keep:
            predictions.append(pred)
    if not rows:
        raise ValueError("frames must hold at least one frame")
    return pd.concat(rows, ignore_index=True), pd.DataFrame(images), predictions


def table1(per_class: pd.DataFrame) -> pd.DataFrame:
    """Table I (§III): per class the mean and SD over images of each metric.

    Args:
        per_class: :func:`evaluate_segmentation`'s per-class rows.

    Returns:
        One row per class (``class``, ``<metric>_mean``, ``<metric>_sd`` in percent for precision,
        recall, IoU and accuracy; NaN where undefined) and ``images``, the images with a defined
        precision.
    """
    out = []
    for cls in CLASS_KEYS:
        sub = per_class[per_class["class"] == cls]
        row: dict[str, object] = {"class": cls}
        for metric in METRICS:
            values = sub[metric].dropna()
            row[f"{metric}_mean"] = float(values.mean()) if len(values) else np.nan
            row[f"{metric}_sd"] = float(values.std(ddof=1)) if len(values) > 1 else np.nan
        row["images"] = int(sub["precision"].notna().sum())
        out.append(row)
    return pd.DataFrame(out)


def summary(per_image: pd.DataFrame) -> pd.DataFrame:
    """Mean and SD over images of the global accuracy, weighted IoU, mean precision and recall."""
    cols = ["global_accuracy", "weighted_iou", "mean_precision", "mean_recall"]
    return pd.DataFrame({"metric": cols, "mean": [per_image[c].mean() for c in cols],
                         "sd": [per_image[c].std(ddof=1) for c in cols]})


def precision_tests(per_class: pd.DataFrame,
                    alpha: float = 0.05) -> tuple[dict | None, pd.DataFrame | None, list[str]]:
    """One-way ANOVA and Tukey HSD of the per-image precision over the classes.

    Images where a class's precision is undefined (the class was never predicted) are left out of
    that class's group; a class with fewer than two defined values is left out of the tests and
    named in the returned list. Returns ``(anova, tukey, dropped)``, ``anova`` with ``F,
    df_between, df_within, p``; ``anova`` and ``tukey`` are None when fewer than two classes are
    left (a network that predicts a single class).
    """
    groups: dict[str, np.ndarray] = {}
    dropped: list[str] = []
    for cls in CLASS_KEYS:
        values = per_class.loc[per_class["class"] == cls, "precision"].dropna().to_numpy()
        if len(values) >= 2:
            groups[cls] = values
        else:
            dropped.append(cls)
    if len(groups) < 2:
        return None, None, dropped
    F, df_b, df_w, p = anova_oneway(groups)
    return {"F": F, "df_between": df_b, "df_within": df_w, "p": p}, tukey_hsd(groups, alpha), dropped


def anova_text(anova: dict, tukey: pd.DataFrame, reference: str = "background") -> str:
    """The §III paragraph: the ANOVA result and which classes' precision is significantly lower
    than ``reference``'s (with the adjusted p and confidence interval of the difference)."""
    p = anova["p"]
    p_text = "p < 1e-5" if p < 1e-5 else f"p = {p:.3g}"
    text = (f"A one-way ANOVA over the precision of the {anova['df_between'] + 1} classes gives "
            f"F({anova['df_between']}, {anova['df_within']}) = {anova['F']:.1f}, {p_text}. ")
    lower = []
    for row in tukey.itertuples():
        if reference not in (row.group1, row.group2) or not row.reject:
            continue
        other = row.group2 if row.group1 == reference else row.group1
        # meandiff = mean(group2) - mean(group1): express as reference minus other
        diff, lo, hi = ((-row.meandiff, -row.upper, -row.lower) if row.group1 == reference
                        else (row.meandiff, row.lower, row.upper))
        if diff > 0:
            lower.append(f"{other} (by {diff:.1f} %, p_adj = {row.p_adj:.2g}, 95 % CI [{lo:.1f}, {hi:.1f}] %)")
    if lower:
        text += f"Tukey's HSD finds the precision significantly lower than {reference}'s for " + "; ".join(lower) + "."
    else:
        text += f"Tukey's HSD finds no class with a precision significantly lower than {reference}'s."
    return text


@dataclass(frozen=True)
class SegmentationSetup(HeldOutSetup):
    """What notebook 02 runs on (made by :func:`prepare`).

    Args:
        params: the checked parameters.
        seed: the study seed (the held-out frames derive from it).
        weights_path: the U-Net's checkpoint.
        frames: the held-out frames (:func:`histostudy.study.held_out.held_out_frames`).
        segmenter: the U-Net (:func:`load_unet`).
    """

    segmenter: UNetRunner


def prepare(params: SegmentationConfig | Mapping, seed: int, *, timer: Timer | None = None) -> SegmentationSetup:
    """The section's set-up: the U-Net of ``params.weights`` and the held-out frames of ``seed``.

    Args:
        params: a :class:`SegmentationConfig`, or a mapping naming its fields (checked into one).
        seed: the study seed.
        timer: ``timer(name)`` -> a context manager timing the frames' pre-rendering (with
            ``render_workers`` > 1); None: untimed.

    Returns:
        The :class:`SegmentationSetup`.

    Raises:
        ValueError: a bad or missing parameter.
        FileNotFoundError: no usable checkpoint (:func:`load_unet`).
    """
    return SegmentationSetup(*prepare_held_out(SegmentationConfig, params, seed, load_unet, timer=timer))


@dataclass(frozen=True, eq=False)
class SegmentationEvaluation:
    """The held-out frames segmented (:func:`evaluation_section`).

    Args:
        per_class: one row per image and class (:func:`evaluate_segmentation`).
        per_image: one row per image.
        predictions: the label images of the first frames.
        part: the report's part (table ``per_image``, value ``segmentation_seconds_median``).
    """

    per_class: pd.DataFrame
    per_image: pd.DataFrame
    predictions: list
    part: SectionPart


def evaluation_section(segmenter, frames: HybridFrames, n_images: int, *, keep: int = 3,
                       timer: Timer | None = None) -> SegmentationEvaluation:
    """Segment the first ``n_images`` held-out frames (:func:`evaluate_segmentation`).

    Args:
        segmenter: the U-Net (``setup.segmenter``).
        frames: the held-out frames (``setup.frames``; frame ``i`` is ``frames.frame(i)``).
        n_images: how many, from frame 0.
        keep: how many predictions to keep for the figure.
        timer: ``timer(name)`` -> a context manager timing the whole (``"render and segment <n>
            frames"``); None: untimed.

    Returns:
        A :class:`SegmentationEvaluation`; its part: the per-image table and the median
        segmentation time (s).

    Raises:
        ValueError: a frame without reference labels, or ``n_images`` 0.
    """
    with timer_or_untimed(timer)(f"render and segment {n_images} frames"):
        per_class, per_image, predictions = evaluate_segmentation(
            segmenter, (frames.frame(i) for i in range(n_images)), keep=keep)
    part = SectionPart(tables={"per_image": (per_image, "Per-image global accuracy, weighted IoU, mean precision "
                                                        "and recall (%)", {"digits": 2})},
                       values={"segmentation_seconds_median": float(per_image["seconds"].median())})
    return SegmentationEvaluation(per_class, per_image, predictions, part)


def table1_part(per_class: pd.DataFrame, per_image: pd.DataFrame) -> SectionPart:
    """Table I and the per-image summary, each value beside the paper's (§III).

    Args:
        per_class: :func:`evaluate_segmentation`'s per-class rows.
        per_image: its per-image rows.

    Returns:
        A part with table ``table1`` (:func:`table1`), table ``summary`` (mean and SD of the global
        accuracy, weighted IoU, mean precision and recall, percent) and the comparisons.
    """
    n_images = int(per_image["image"].nunique())
    table = table1(per_class)
    comparisons = [dict(key=f"table1.{row['class']}.{metric}", label=f"{row['class']}: {metric}",
                        ours=(row[f"{metric}_mean"], row[f"{metric}_sd"]), unit="%", digits=1)
                   for row in table.to_dict("records") for metric in METRICS]
    overall = summary(per_image)
    for metric, key in SUMMARY_KEYS.items():
        row = overall[overall["metric"] == metric].iloc[0]
        comparisons.append(dict(key=key, label=metric.replace("_", " "), ours=(row["mean"], row["sd"]), unit="%",
                                digits=1))
    comparisons.append(dict(key="seg.n_images", label="Evaluation images", ours=n_images,
                            note="held-out synthetic hybrid frames (split 'eval'); the paper's were annotated real "
                                 "frames"))
    return SectionPart(
        tables={"table1": (table, f"Table I: per-class metrics, mean and SD over {n_images} held-out frames (%)",
                           {"digits": 1}),
                "summary": (overall, "Global accuracy, frequency-weighted IoU, mean precision and recall (%)",
                            {"digits": 2})},
        comparisons=tuple(comparisons))


def background_minus_screws_ci(tukey: pd.DataFrame) -> tuple[float, float] | None:
    """Tukey's confidence interval of background minus screws precision (the paper's orientation
    of the difference, percent), or None when the pair is not in ``tukey``."""
    pair = tukey[tukey["group1"].isin(["background", "screws"]) & tukey["group2"].isin(["background", "screws"])]
    if not len(pair):
        return None
    r = pair.iloc[0]
    # meandiff = group2 - group1, so with background as group1 the interval flips sign
    return (-r["upper"], -r["lower"]) if r["group1"] == "background" else (r["lower"], r["upper"])


@dataclass(frozen=True, eq=False)
class PrecisionTests:
    """The ANOVA and Tukey HSD of the classes' precision (:func:`precision_tests_section`).

    Args:
        paragraph: the §III paragraph on them.
        tukey: the Tukey HSD table (None when fewer than two classes could be tested).
        part: the report's part.
    """

    paragraph: str
    tukey: pd.DataFrame | None
    part: SectionPart


def precision_tests_section(per_class: pd.DataFrame) -> PrecisionTests:
    """One-way ANOVA and Tukey's HSD of the per-image precision over the classes (§II-E.1, §III).

    A class with fewer than two images of defined precision is left out (and named).

    Args:
        per_class: :func:`evaluate_segmentation`'s per-class rows.

    Returns:
        A :class:`PrecisionTests`; its part: table ``tukey_precision``, the ANOVA (F, degrees of
        freedom, p) and the background-minus-screws interval beside the paper's, and the
        paragraph (with fewer than two classes, that no ANOVA was computed).
    """
    anova, tukey, dropped = precision_tests(per_class)
    label = "ANOVA F of precision over classes"
    if anova is None or tukey is None:
        paragraph = (f"No ANOVA: fewer than two classes have a defined precision in two or more images "
                     f"(left out: {', '.join(dropped)}).")
        return PrecisionTests(paragraph, None, SectionPart(
            comparisons=(dict(key="seg.anova_F", label=label, ours="not computed", note=paragraph),),
            texts=(paragraph,)))
    comparisons = [dict(key="seg.anova_F", label=label, ours=anova["F"], digits=1),
                   dict(key="seg.anova_df_between", label="ANOVA degrees of freedom, between",
                        ours=anova["df_between"]),
                   dict(key="seg.anova_df_within", label="ANOVA degrees of freedom, within", ours=anova["df_within"]),
                   dict(key="seg.anova_p", label="ANOVA p", ours=f"{anova['p']:.2g}")]
    ci = background_minus_screws_ci(tukey)
    if ci is not None:
        comparisons.append(dict(key="seg.tukey_screws_vs_background_ci",
                                label="Tukey 95 % CI, background minus screws precision",
                                ours=f"[{ci[0]:.1f}, {ci[1]:.1f}]", unit="%"))
    paragraph = anova_text(anova, tukey)
    if dropped:
        paragraph += f" Left out (fewer than two images with a defined precision): {', '.join(dropped)}."
    return PrecisionTests(paragraph, tukey, SectionPart(
        tables={"tukey_precision": (tukey, "Tukey HSD of the per-image precision (meandiff = group2 - group1, %)",
                                    {"digits": 3})},
        comparisons=tuple(comparisons), texts=(paragraph,)))


def stand_ins_part(segmenter, weights_path: Path, per_image: pd.DataFrame,
                   detector_shape: tuple[int, int]) -> SectionPart:
    """What stands in for the annotated frames and the GPU-trained U-Net, and the median time to
    segment one frame.

    Args:
        segmenter: the U-Net (its manifest and input scale are named).
        weights_path: its checkpoint.
        per_image: :func:`evaluate_segmentation`'s per-image rows (their count and ``seconds``).
        detector_shape: the frames' ``(rows, cols)``, pixels.

    Returns:
        A part with the stand-ins and one paragraph.
    """
    manifest = segmenter.manifest
    return SectionPart(stand_ins=(
        ("310 manually annotated porcine and phantom fluoroscopy frames",
         f"{len(per_image)} held-out synthetic hybrid frames (procedural background, physical transducer "
         "at a random §II-B.2 pose, Poisson noise) with the digital model's labels in the true pose"),
        ("U-Net trained on GPU (512x512 crops, 64-1024 channels)",
         f"the shipped CPU-trained {network_description(manifest['config'])} at input scale {segmenter.scale}: "
         f"{training_summary(manifest)} (manifest {weights_path.with_suffix('.json').name})")),
        texts=(f"Segmentation takes a median {per_image['seconds'].median():.2f} s per full "
               f"{detector_shape[1]}x{detector_shape[0]} frame on this machine "
               f"(downscaled by {segmenter.scale}, logits upsampled to full size).",))
