"""Notebook 03's section (§II-B.4 eq. 4, §II-E.2, §III): the VGG19's azimuth and elevation on the
held-out hybrid frames against the true pose (MAE, Pearson, Moore-Penrose fit), the direction error and,
beyond the paper, the conic initialiser beside it; each heading's part a
:class:`~histostudy.study.section.SectionPart` (docs/study-sections.md, "03").
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.core import as_generator
from histostudy.learning import (
    LearnedOrientation,
    OracleSegmenter,
    angles_from_direction,
    beam_direction_of_pose,
    direction_candidates,
    orientation_angle_error,
    training_summary,
    wrap_angle,
)
from histostudy.pose import ConicOrientation

from ..held_out import HeldOutConfig, HeldOutSetup, network_description, prepare_held_out, resolve_weights
from ..section import SectionPart, Timer, check_bool, timer_or_untimed
from ..stats import angle_statistics

SECTION = "03_orientation"
TITLE = "03 · Orientation regression with VGG19: azimuth and elevation (§II-B.4, §II-E.2, §III)"

#: Seed of the initialiser comparison's one random stream (the conic fit's RANSAC, shared by all
#: sources and frames in order). Fixed rather than spawned from the study seed: the comparison
#: has always drawn from ``default_rng(0)``, and its reported numbers rest on that stream.
INITIALISER_RNG_SEED = 0


@dataclass(frozen=True)
class OrientationConfig(HeldOutConfig):
    """Notebook 03's parameters, checked (the fields of :class:`histostudy.study.held_out.HeldOutConfig`
    and one of its own); built from the parameters cell by ``OrientationConfig.from_parameters(globals())``.

    Args:
        photons_per_pixel: unattenuated photons per detector pixel of the frames (dose, > 0).
        n_splats: splats per model point (>= 1).
        splat_sigma_mm: SD of each splat's jitter, mm (> 0).
        render_spacing_mm: grid spacing of the rendering and reference-label models, mm.
        background: the frames' scene, one of :data:`histostudy.imaging.BACKGROUNDS`.
        n_eval_images: held-out frames to evaluate (>= 1; the angle statistics need 3).
        weights: the checkpoint to evaluate (a path); ``""``: the shipped one.
        cache_frames: read the frames from (or render them into) the frame cache.
        render_workers: processes that pre-render the uncached frames (>= 1; needs ``cache_frames``).
        geometric_initialiser: also evaluate the conic initialiser on the same frames.

    Raises:
        ValueError: a bad value, naming the parameter, its value and what it must be (or, from
            ``from_parameters``, the parameters the mapping lacks).
    """

    geometric_initialiser: bool

    NOTEBOOK = "03"

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "geometric_initialiser", check_bool(self.geometric_initialiser,
                                                                     "geometric_initialiser"))


def load_vgg19(weights: str | os.PathLike = "") -> tuple[LearnedOrientation, Path]:
    """The VGG19 regressor to evaluate and its checkpoint path.

    Args:
        weights: a checkpoint path; ``""``: the shipped ``data/models/vgg19_standard.safetensors``.

    Returns:
        ``(source, path)``, ``source`` a :class:`histostudy.learning.LearnedOrientation`.

    Raises:
        FileNotFoundError: no ``weights`` given and no usable shipped VGG19 (names the
            ``histostudy train orientation`` command that makes it).
    """
    path = resolve_weights(weights, "vgg19_standard", "VGG19", "orientation")
    return LearnedOrientation.load(path), path


@dataclass(frozen=True)
class OrientationSetup(HeldOutSetup):
    """What notebook 03 runs on (made by :func:`prepare`).

    Args:
        params: the checked parameters.
        seed: the study seed (the held-out frames derive from it).
        weights_path: the VGG19's checkpoint.
        frames: the held-out frames (:func:`histostudy.study.held_out.held_out_frames`).
        source: the VGG19 (:func:`load_vgg19`).
    """

    source: LearnedOrientation


def prepare(params: OrientationConfig | Mapping, seed: int, *, timer: Timer | None = None) -> OrientationSetup:
    """The section's set-up: the VGG19 of ``params.weights`` and the held-out frames of ``seed``.

    Args:
        params: an :class:`OrientationConfig`, or a mapping naming its fields (checked into one).
        seed: the study seed.
        timer: ``timer(name)`` -> a context manager timing the frames' pre-rendering (with
            ``render_workers`` > 1); None: untimed.

    Returns:
        The :class:`OrientationSetup`.

    Raises:
        ValueError: a bad or missing parameter.
        FileNotFoundError: no usable checkpoint (:func:`load_vgg19`).
    """
    return OrientationSetup(*prepare_held_out(OrientationConfig, params, seed, load_vgg19, timer=timer))


def evaluate_orientation(source, frames: Iterable, rng: np.random.Generator | None = None) -> pd.DataFrame:
    """The source's azimuth and elevation of each frame against the true pose's (§II-B.4, §II-E.2).

    Args:
        source: anything with ``estimate(frame, rng)`` returning ``(azimuth, elevation)`` in rad,
            in the view's detector frame (e.g. :class:`histostudy.learning.LearnedOrientation`).
        frames: frames with their true ``T_carm_transducer`` (any iterable).
        rng: passed to ``source.estimate``.

    Returns:
        One row per frame: reference and predicted azimuth and elevation (deg), the azimuth error
        wrapped to (-180°, 180°], the elevation error, the angle between the predicted and the
        reference direction (deg; :func:`histostudy.learning.orientation_angle_error`) and the
        ``seconds`` the source took.

    Raises:
        ValueError: a frame without a true pose, or no frame at all.
    """
    rows = []
    for i, frame in enumerate(frames):
        if frame.T_carm_transducer is None:
            raise ValueError(f"frame {i} (view {frame.view.name!r}) has no true pose to evaluate against")
        ref_az, ref_el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        t0 = time.perf_counter()
        az, el = source.estimate(frame, rng)
        seconds = time.perf_counter() - t0
        rows.append({"image": i, "view": frame.view.name,
                     "azimuth_ref_deg": np.degrees(ref_az), "azimuth_pred_deg": np.degrees(az),
                     "elevation_ref_deg": np.degrees(ref_el), "elevation_pred_deg": np.degrees(el),
                     "azimuth_error_deg": float(np.degrees(wrap_angle(az - ref_az))),
                     "elevation_error_deg": float(np.degrees(el - ref_el)),
                     "direction_error_deg": float(np.degrees(orientation_angle_error(az, el, ref_az, ref_el))),
                     "seconds": seconds})
    if not rows:
        raise ValueError("frames must hold at least one frame")
    return pd.DataFrame(rows)


def angle_table(results: pd.DataFrame) -> pd.DataFrame:
    """The §III statistics per angle.

    Args:
        results: :func:`evaluate_orientation`'s rows.

    Returns:
        One row per angle (azimuth, wrapped; elevation): MAE and SD (deg), Pearson r (percent) and p,
        intercept (deg), slope, R² and n.
    """
    rows = []
    for angle, wrap in (("azimuth", True), ("elevation", False)):
        s = angle_statistics(np.radians(results[f"{angle}_pred_deg"]), np.radians(results[f"{angle}_ref_deg"]),
                             wrap=wrap)
        rows.append({"angle": angle, "mae_deg": s["mae_deg"], "sd_deg": s["sd_deg"],
                     "pearson_percent": 100.0 * s["pearson_r"], "pearson_p": s["pearson_p"],
                     "intercept_deg": s["intercept_deg"], "slope": s["slope"], "r2": s["r2"], "n": s["n"]})
    return pd.DataFrame(rows)


def direction_error_summary(results: pd.DataFrame, misread_deg: float = 30.0) -> dict:
    """The direction error of :func:`evaluate_orientation`'s rows (beyond the paper, which reports
    the two angles only).

    Args:
        results: :func:`evaluate_orientation`'s rows (column ``direction_error_deg``).
        misread_deg: the error beyond which a frame counts as misread, deg: its initialisation must
            lean on the other view (:func:`histostudy.pose.estimate_pose`'s per-view direction starts).

    Returns:
        ``mean_deg``, ``sd_deg`` (NaN for one row), ``median_deg``, ``p90_deg``,
        ``misread_fraction``, ``misread_deg`` and ``n``.

    Raises:
        ValueError: ``misread_deg`` not finite and > 0, or no rows.
    """
    if not (np.isfinite(misread_deg) and misread_deg > 0):
        raise ValueError(f"misread_deg must be finite and > 0, got {misread_deg!r}")
    e = np.asarray(results["direction_error_deg"], dtype=np.float64)
    if e.size == 0:
        raise ValueError("results must hold at least one row")
    return {"mean_deg": float(e.mean()), "sd_deg": float(e.std(ddof=1)) if e.size > 1 else float("nan"),
            "median_deg": float(np.median(e)), "p90_deg": float(np.percentile(e, 90)),
            "misread_fraction": float(np.mean(e > misread_deg)), "misread_deg": float(misread_deg), "n": int(e.size)}


def _source_candidates(source, frame, rng) -> tuple[np.ndarray, bool]:
    own = getattr(source, "candidates", None)
    if own is not None:
        pair, fell_back = own(frame, rng)
        return np.asarray(pair, dtype=np.float64), bool(fell_back)
    azimuth_rad, elevation_rad = source.estimate(frame, rng)
    return direction_candidates(azimuth_rad, elevation_rad, frame.view), False


def candidate_errors(sources: dict, frames: Iterable, rng) -> pd.DataFrame:
    """What the pose initialisation starts from, per frame and orientation source (beyond the paper).

    Every source gives each view two candidate world directions of the transducer axis: eq. 4's
    mirror pair of its ``(azimuth, elevation)``, or, for a source with a ``candidates(frame, rng)``
    method (:class:`histostudy.pose.ConicOrientation`), its own pair; the pose initialisation
    resolves the pair across views (§II-B.4). For an ``(azimuth, elevation)`` source the nearer
    candidate's angle is its direction error of :func:`evaluate_orientation`.

    Args:
        sources: ``{name: orientation source}``, in report order.
        frames: frames with their true ``T_carm_transducer`` (any iterable).
        rng: a seed or a Generator: the one stream every source draws from, frame by frame in order.

    Returns:
        One row per frame and source: the angle (deg) between the true focal direction and the
        nearer candidate, that candidate's azimuth and elevation errors in the view (deg; azimuth
        wrapped), the reference elevation, whether the source fell back to another
        (``fell_back``) and its ``seconds``.

    Raises:
        ValueError: ``sources`` not a non-empty dict, a frame without a true pose, or no frame.
    """
    if not isinstance(sources, dict) or not sources:
        raise ValueError(f"sources must be a non-empty dict {{name: orientation source}}, got {sources!r}")
    rng = as_generator(rng)
    rows = []
    for i, frame in enumerate(frames):
        if frame.T_carm_transducer is None:
            raise ValueError(f"frame {i} (view {frame.view.name!r}) has no true pose to evaluate against")
        truth = beam_direction_of_pose(frame.T_carm_transducer)
        ref_az, ref_el = angles_from_direction(truth, frame.view)
        for name, source in sources.items():
            t0 = time.perf_counter()
            pair, fell_back = _source_candidates(source, frame, rng)
            seconds = time.perf_counter() - t0
            pair = pair / np.linalg.norm(pair, axis=1, keepdims=True)
            nearest = pair[int(np.argmax(pair @ truth))]
            az, el = angles_from_direction(nearest, frame.view)
            rows.append({"image": i, "view": frame.view.name, "source": name,
                         "candidate_error_deg": float(np.degrees(np.arccos(np.clip(nearest @ truth, -1.0, 1.0)))),
                         "azimuth_error_deg": float(np.degrees(wrap_angle(az - ref_az))),
                         "elevation_error_deg": float(np.degrees(el - ref_el)),
                         "elevation_ref_deg": float(np.degrees(ref_el)),
                         "fell_back": fell_back, "seconds": seconds})
    if not rows:
        raise ValueError("frames must hold at least one frame")
    return pd.DataFrame(rows)


def candidate_error_summary(per_frame: pd.DataFrame, misread_deg: float = 30.0) -> pd.DataFrame:
    """The candidate errors summarised per source.

    Args:
        per_frame: :func:`candidate_errors`' rows.
        misread_deg: the angle beyond which a frame counts as misread, deg.

    Returns:
        One row per source: median, 90th percentile and mean of the nearer candidate's angle
        (deg), the fraction of frames off by more than ``misread_deg``, the azimuth and elevation
        MAE of the nearer candidate (deg), the fraction of frames the source fell back on, the
        median seconds and n.

    Raises:
        ValueError: ``misread_deg`` not finite and > 0.
    """
    if not (np.isfinite(misread_deg) and misread_deg > 0):
        raise ValueError(f"misread_deg must be finite and > 0, got {misread_deg!r}")
    rows = []
    for name, g in per_frame.groupby("source", sort=False):
        e = g["candidate_error_deg"].to_numpy()
        rows.append({"source": name, "median_deg": float(np.median(e)), "p90_deg": float(np.percentile(e, 90)),
                     "mean_deg": float(e.mean()), "misread_fraction": float(np.mean(e > misread_deg)),
                     "azimuth_mae_deg": float(g["azimuth_error_deg"].abs().mean()),
                     "elevation_mae_deg": float(g["elevation_error_deg"].abs().mean()),
                     "fallback_fraction": float(g["fell_back"].mean()), "seconds_median": float(g["seconds"].median()),
                     "n": int(len(g))})
    return pd.DataFrame(rows)


def scatter_figure(results: pd.DataFrame, table: pd.DataFrame | None = None):
    """Predicted against reference azimuth and elevation with the identity line and the
    Moore-Penrose fit. Azimuth predictions are drawn on the branch nearest the reference
    (``ref + wrapped error``), the branch the statistics use.

    Args:
        results: :func:`evaluate_orientation`'s rows.
        table: the ``angle_statistics`` table of :func:`angle_statistics_part` (its fit and MAE);
            None: computed from ``results``.

    Returns:
        A matplotlib figure (pyplot-managed) of two panels, azimuth and elevation (deg).
    """
    import matplotlib.pyplot as plt

    table = angle_table(results) if table is None else table
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
    for ax, angle, lim in zip(axes, ("azimuth", "elevation"), ((-180, 180), (0, 90))):
        ref = results[f"{angle}_ref_deg"].to_numpy()
        pred = ref + results[f"{angle}_error_deg"].to_numpy()
        ax.scatter(ref, pred, s=10, alpha=0.7, label="frames")
        ax.plot(lim, lim, "k--", lw=1, label="identity")
        row = table[table["angle"] == angle].iloc[0]
        x = np.array(lim, dtype=float)
        ax.plot(x, row["intercept_deg"] + row["slope"] * x, "r-", lw=1,
                label=f"fit: {row['slope']:.3f} x {row['intercept_deg']:+.2f}°, R² {row['r2']:.3f}")
        ax.set_xlim(lim)
        ax.set_xlabel(f"reference {angle} (deg)")
        ax.set_ylabel(f"predicted {angle} (deg)")
        ax.set_title(f"{angle}: MAE {row['mae_deg']:.2f} ± {row['sd_deg']:.2f}°")
        ax.legend(loc="upper left", fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
    fig.tight_layout()
    return fig


@dataclass(frozen=True, eq=False)
class AngleEvaluation:
    """The held-out frames' angles (:func:`evaluation_section`).

    Args:
        results: the per-frame rows (:func:`evaluate_orientation`).
        part: the report's part (table ``angles_per_frame``, value ``regression_seconds_median``).
    """

    results: pd.DataFrame
    part: SectionPart


def evaluation_section(source, frames, n_images: int, *, timer: Timer | None = None) -> AngleEvaluation:
    """Regress the angles of the first ``n_images`` held-out frames (:func:`evaluate_orientation`).

    Args:
        source: the VGG19 (``setup.source``).
        frames: anything with ``frame(i)``, e.g. :class:`histostudy.learning.HybridFrames`
            (``setup.frames``).
        n_images: how many, from frame 0.
        timer: ``timer(name)`` -> a context manager timing the whole (``"render and regress <n>
            frames"``); None: untimed.

    Returns:
        An :class:`AngleEvaluation`; its part: the per-frame table and the median regression time (s).

    Raises:
        ValueError: a frame without a true pose, or ``n_images`` 0.
    """
    with timer_or_untimed(timer)(f"render and regress {n_images} frames"):
        results = evaluate_orientation(source, (frames.frame(i) for i in range(n_images)))
    return AngleEvaluation(results, SectionPart(
        tables={"angles_per_frame": (results, "Reference and predicted angles per held-out frame (deg)",
                                     {"digits": 2})},
        values={"regression_seconds_median": float(results["seconds"].median())}))


def angle_statistics_part(results: pd.DataFrame) -> SectionPart:
    """The §III statistics per angle, each beside the paper's (§II-E.2).

    Args:
        results: :func:`evaluate_orientation`'s rows.

    Returns:
        A part with table ``angle_statistics`` (per angle: MAE and SD in deg, Pearson r in percent
        and its p, the Moore-Penrose intercept in deg, slope and R², n) and the comparisons.
    """
    table = angle_table(results)
    comparisons = []
    for row in table.itertuples():
        a = row.angle
        comparisons += [
            dict(key=f"angles.{a}.mae", label=f"{a}: mean absolute error", ours=(row.mae_deg, row.sd_deg), unit="deg",
                 digits=2),
            dict(key=f"angles.{a}.pearson", label=f"{a}: Pearson correlation", ours=row.pearson_percent, unit="%",
                 digits=1, note=f"p = {row.pearson_p:.2g}"),
            dict(key=f"angles.{a}.slope", label=f"{a}: slope (Moore–Penrose)", ours=row.slope, digits=3),
            dict(key=f"angles.{a}.intercept", label=f"{a}: intercept", ours=row.intercept_deg, unit="deg", digits=3),
            dict(key=f"angles.{a}.r2", label=f"{a}: R²", ours=row.r2, digits=3)]
    return SectionPart(tables={"angle_statistics": (table, f"Angle regression statistics over {len(results)} "
                                                           "held-out frames", {"digits": 3})},
                       comparisons=tuple(comparisons))


def direction_error_part(results: pd.DataFrame) -> SectionPart:
    """The direction error (beyond the paper).

    Args:
        results: :func:`evaluate_orientation`'s rows.

    Returns:
        A part with value ``direction_error`` (:func:`direction_error_summary`) and its comparison.
    """
    direction = direction_error_summary(results)
    return SectionPart(values={"direction_error": direction}, comparisons=(dict(
        key="angles.direction.mae", label="direction: mean angle between predicted and reference axis",
        ours=(direction["mean_deg"], direction["sd_deg"]), unit="deg", digits=2, paper_key="",
        note=f"median {direction['median_deg']:.1f}°, 90th percentile {direction['p90_deg']:.1f}°; "
             f"{100 * direction['misread_fraction']:.0f} % of frames off by > {direction['misread_deg']:.0f}°"),))


def orientation_initialisers(vgg19, unet=None) -> dict:
    """The orientation initialisers compared in notebook 03, by report name.

    Args:
        vgg19: the VGG19 (§II-B.4), also the conics' fallback in views without a usable ellipse.
        unet: the segmenter whose labels the first conic initialiser reads; None: that one is left out.

    Returns:
        ``{"VGG19 (§II-B.4)": vgg19, "conic, U-Net labels": ..., "conic, reference labels": ...}``,
        the last on the reference labels (the bound a perfect segmentation gives).
    """
    initialisers = {"VGG19 (§II-B.4)": vgg19}
    if unet is not None:
        initialisers["conic, U-Net labels"] = ConicOrientation(segmenter=unet, fallback=vgg19)
    initialisers["conic, reference labels"] = ConicOrientation(segmenter=OracleSegmenter(), fallback=vgg19)
    return initialisers


def initialiser_key(name: str) -> str:
    """The results key of an initialiser's report name: ``"vgg19"``, ``"conic_U-Net"``,
    ``"conic_reference"``."""
    return "vgg19" if name.startswith("VGG19") else name.replace("conic, ", "conic_").split()[0]


@dataclass(frozen=True, eq=False)
class InitialiserComparison:
    """The initialisers on the held-out frames (:func:`initialiser_comparison_section`).

    Args:
        per_frame: the rows of :func:`candidate_errors`.
        summary: their :func:`candidate_error_summary`.
        part: the report's part.
    """

    per_frame: pd.DataFrame
    summary: pd.DataFrame
    part: SectionPart


def initialiser_comparison_section(initialisers: dict, frames: list, *, rng,
                                   timer: Timer | None = None) -> InitialiserComparison:
    """The initialisers' candidate directions on the same frames (beyond the paper).

    Args:
        initialisers: ``{name: orientation source}`` (:func:`orientation_initialisers`).
        frames: frames with their true pose.
        rng: a seed or a Generator, the one stream all draw from (:data:`INITIALISER_RNG_SEED` in
            the notebook).
        timer: ``timer(name)`` -> a context manager timing the whole; None: untimed.

    Returns:
        An :class:`InitialiserComparison`; its part: tables ``initialiser_candidates`` and
        ``initialiser_summary`` and each initialiser's median nearer-candidate angle.

    Raises:
        ValueError: as :func:`candidate_errors`.
    """
    with timer_or_untimed(timer)(f"candidate directions of {len(initialisers)} initialisers on {len(frames)} frames"):
        per_frame = candidate_errors(initialisers, frames, rng)
    summary = candidate_error_summary(per_frame)
    comparisons = tuple(dict(
        key=f"initialiser.{initialiser_key(row.source)}.direction", label=f"{row.source}: nearer candidate's angle "
        "to the axis", ours=row.median_deg, unit="deg", digits=2, paper_key="",
        note=f"median; 90th percentile {row.p90_deg:.1f}°; azimuth / elevation MAE {row.azimuth_mae_deg:.2f}° / "
             f"{row.elevation_mae_deg:.2f}°; {100 * row.fallback_fraction:.0f} % fell back to the VGG19")
        for row in summary.itertuples())
    return InitialiserComparison(per_frame, summary, SectionPart(
        tables={"initialiser_candidates": (per_frame, "Nearer candidate direction per frame and initialiser (deg)",
                                           {"digits": 2}),
                "initialiser_summary": (summary, "Initialisers on the held-out frames: nearer candidate's angle to "
                                        "the true axis (deg), its azimuth and elevation MAE (deg), fallbacks to the "
                                        "VGG19, seconds", {"digits": 3})},
        comparisons=comparisons))


def stand_ins_part(vgg19, weights_path: Path, n_images: int) -> SectionPart:
    """What stands in for the annotated frames and the GPU-trained VGG19, and the note on how the
    azimuth statistics treat wrapping and elevations near 0.

    Args:
        vgg19: the VGG19 (its manifest is named).
        weights_path: its checkpoint.
        n_images: the frames evaluated.

    Returns:
        A part with the stand-ins and one paragraph.
    """
    manifest = vgg19.manifest
    return SectionPart(stand_ins=(
        ("manually annotated porcine and phantom fluoroscopy frames",
         f"{n_images} held-out synthetic hybrid frames with the true pose as the reference"),
        ("VGG19 trained on GPU for 400,000 iterations",
         f"the shipped CPU-trained {network_description(manifest['config'])}: {training_summary(manifest)} "
         f"(manifest {weights_path.with_suffix('.json').name})")),
        texts=("Azimuth errors are wrapped to (−180°, 180°] and the azimuth statistics use each prediction on the "
               "branch nearest its reference. Near elevation 0 (transducer axis along the beam) the azimuth is "
               "ill-defined, so large azimuth errors there cost little in direction: the direction error "
               "(the angle between the predicted and the reference axis, beyond the paper) is what the pose "
               "initialisation sees.",))
