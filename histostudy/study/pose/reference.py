"""The paper's reference of Table II (§II-D, §II-E.3): each experiment's treatment simulated about
its true centre pose, the post-treatment CBCT simulated and the treated zone segmented
automatically (the stand-in for the paper's manual annotation). C-arm (CBCT) frame, mm; CBCT
intensities in HU (docs/pose-study.md, "The CBCT reference").
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.imaging import Anatomy, PhantomSpec, Volume, phantom_mask, phantom_volume
from histostudy.transducer import TransducerModel
from histostudy.treatment import (
    STUDY_PLAN_INSET_MM,
    STUDY_PLAN_SPACING_MM,
    TreatmentZone,
    plan_treatment,
    scan_treated_zone,
)

from .experiments import PoseExperiment, PoseStudyConfig, draw_experiments
from .geometry import DIRECTIONS, bubble_cloud_centre_mm, transducer_axes

__all__ = ["REFERENCE_COLUMNS", "cbct_reference", "phantom_placement", "reference_by_experiment"]

#: Columns :func:`experiment_metrics` reads from a reference table (:func:`cbct_reference`).
REFERENCE_COLUMNS = ("experiment", "centroid_x", "centroid_y", "centroid_z", "sphere_x", "sphere_y", "sphere_z",
                     "sphere_radius_mm", *(f"ref_radius_{d}" for d in DIRECTIONS),
                     *(f"axis_{d}_{a}" for d in DIRECTIONS for a in "xyz"))


def phantom_placement(scene: Anatomy, centre_mm=(0.0, 0.0, 0.0)) -> tuple[PhantomSpec, np.ndarray]:
    """The layered phantom of a scene as :mod:`histostudy.imaging.cbct` models it (§II-D.1).

    A phantom scene records its cube's edge, centre, yaw about the vertical axis and layer
    thickness; its layers are stacked vertically as poured, so the phantom frame's +z is world
    ``-y`` (up). The layers' phase is :class:`~histostudy.imaging.PhantomSpec`'s (the fluoroscopy
    never sees it). A scene without a phantom (abdomen) gets the default 5 cm phantom at ``centre_mm``.

    Args:
        scene: the experiment's :class:`~histostudy.imaging.Anatomy`.
        centre_mm: the default phantom's centre where the scene has none (C-arm frame, mm).

    Returns:
        ``(PhantomSpec, T_carm_phantom)`` (4x4, mm; phantom -> C-arm).

    Raises:
        TypeError: ``scene`` is not an Anatomy.
    """
    if not isinstance(scene, Anatomy):
        raise TypeError(f"scene must be a histostudy.imaging.anatomy.Anatomy, got {type(scene).__name__}")
    meta = scene.meta
    up = rotation_about_axis([1.0, 0.0, 0.0], np.pi / 2)  # phantom z -> world -y
    if "phantom_center_mm" not in meta:
        return PhantomSpec(), make_transform(up, np.asarray(centre_mm, dtype=np.float64))
    spec = PhantomSpec(size_mm=float(meta.get("phantom_edge_mm", PhantomSpec.size_mm)),
                       layer_thickness_mm=float(meta.get("layer_mm", PhantomSpec.layer_thickness_mm)))
    yaw = rotation_about_axis([0.0, 1.0, 0.0], np.deg2rad(float(meta.get("phantom_yaw_deg", 0.0))))
    return spec, make_transform(yaw @ up, np.asarray(meta["phantom_center_mm"], dtype=np.float64))


def _positive(value, name: str, allow_zero: bool = False):
    arr = np.asarray(value, dtype=np.float64)
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr < 0) or (not allow_zero and np.any(arr == 0)):
        raise ValueError(f"{name} must be finite and {'>= 0' if allow_zero else '> 0'} (mm or HU), got {value!r}")
    return value


def phantom_and_mask(spec: PhantomSpec, T_carm_phantom: np.ndarray, spacing_mm) -> tuple[Volume, np.ndarray]:
    """The phantom set-up rasterised (:func:`~histostudy.imaging.phantom_volume`) and its cube's mask
    (:func:`~histostudy.imaging.phantom_mask`), both read-only: the last placement's are kept, since
    the configurations of an experiment (notebook 07) and its labs treat the same phantom in turn.

    Args:
        spec: the phantom.
        T_carm_phantom: (4, 4) rigid, phantom -> C-arm (mm).
        spacing_mm: the grid's voxel (mm, scalar or ``(3,)``, > 0).

    Returns:
        ``(phantom, mask)``: HU on the grid, C-arm frame; boolean ``[z, y, x]``.

    Raises:
        ValueError: as :func:`~histostudy.imaging.phantom_volume`.
    """
    T = np.ascontiguousarray(T_carm_phantom, dtype=np.float64)
    spacing = tuple(float(v) for v in np.atleast_1d(np.asarray(spacing_mm, dtype=np.float64)))
    return _phantom_and_mask(spec, T.shape, T.tobytes(), spacing)


@functools.lru_cache(maxsize=1)
def _phantom_and_mask(spec: PhantomSpec, shape: tuple, T_bytes: bytes, spacing: tuple) -> tuple[Volume, np.ndarray]:
    T = np.frombuffer(T_bytes, dtype=np.float64).reshape(shape)
    phantom = phantom_volume(spec, T, spacing_mm=spacing[0] if len(spacing) == 1 else spacing)
    mask = phantom_mask(phantom, spec, T)
    phantom.data.setflags(write=False)
    mask.setflags(write=False)
    return phantom, mask


def _treat_and_scan(exp: PoseExperiment, spec: PhantomSpec, T_carm_phantom: np.ndarray, *, physical: TransducerModel,
                    config: PoseStudyConfig, rng: np.random.Generator, phantom_voxel_mm, cbct_voxel_mm,
                    cbct_blur_mm: float, cbct_noise_hu: float, treatment_spacing_mm, treatment_inset_mm):
    """The paper's treatment of one pose experiment and its post-treatment CBCT, segmented.

    The sphere of radius ``r`` is planned about the centre pose's TCP (the geometric focal point)
    on the centre pose's axes; the robot translates the transducer through the plan without
    turning it (its repeatability noise added); the bubble clouds sit at the physical
    transducer's focal point plus ``config.bubble_offset_mm`` for each reached pose.
    """
    T_c = exp.T_true["centre"]
    R = T_c[:3, :3]
    plan = plan_treatment(TreatmentZone(T_c[:3, 3], 2.0 * exp.radius_mm), treatment_spacing_mm, axes=R,
                          inset_mm=treatment_inset_mm)
    reached = np.repeat(T_c[None], len(plan), axis=0)
    reached[:, :3, 3] = plan.points_mm + rng.normal(0.0, config.robot_repeatability_mm, plan.points_mm.shape)
    phantom, roi = phantom_and_mask(spec, T_carm_phantom, phantom_voxel_mm)
    seg, post = scan_treated_zone(phantom, roi, reached, physical.focal_point_mm, config.bubble_offset_mm, spec=spec,
                                  T_carm_phantom=T_carm_phantom, rng=rng, blur_sigma_mm=cbct_blur_mm,
                                  noise_sd_hu=cbct_noise_hu, voxel_mm=cbct_voxel_mm)
    return seg, post, len(plan)


def cbct_reference(config: PoseStudyConfig, *, physical: TransducerModel, seed: int,
                   records: pd.DataFrame | None = None, phantom_voxel_mm=0.5, cbct_voxel_mm=1.0,
                   cbct_blur_mm: float = 0.5, cbct_noise_hu: float = 20.0,
                   treatment_spacing_mm=STUDY_PLAN_SPACING_MM, treatment_inset_mm=STUDY_PLAN_INSET_MM,
                   keep_volumes: bool = False, progress: Callable[[str], None] | None = None,
                   experiments: Sequence[int] | None = None) -> pd.DataFrame:
    """The paper's reference of Table II (§II-D, §II-E.3): the treated zone in a post-treatment CBCT.

    For each experiment of :func:`~histostudy.study.pose.experiments.run_pose_study` with the same
    ``config`` and ``seed`` (the set-ups redrawn, no rendering): a sphere of radius ``r`` treated
    about the true centre pose (:func:`histostudy.treatment.plan_treatment`; bubble clouds at the
    physical focal point plus ``config.bubble_offset_mm``), the scene's layered phantom
    (:func:`phantom_placement`) mixed there, a post-treatment CBCT simulated and the zone segmented
    (:func:`histostudy.treatment.scan_treated_zone`, the automatic stand-in for the manual annotation).

    Args:
        config: the study's parameters.
        physical: the physical transducer.
        seed: the study's integer seed.
        records: ``run_pose_study``'s rows: only their experiments are treated, each one's true centre
            checked against the redrawn set-up; None: every experiment (or ``experiments``).
        phantom_voxel_mm: grid of the true phantom (mm, > 0).
        cbct_voxel_mm: voxel of the simulated CBCT (mm, > 0).
        cbct_blur_mm: the CBCT's Gaussian blur (mm, >= 0).
        cbct_noise_hu: the CBCT's noise SD (HU, >= 0).
        treatment_spacing_mm: the plan's lattice spacing (LR, TB, depth; mm).
        treatment_inset_mm: the plan's ellipsoid inset (mm).
        keep_volumes: also return the volumes (column ``_volumes``).
        progress: called with a line per experiment; None: silent.
        experiments: treat only these experiment indices.

    Returns:
        One row per experiment (C-arm frame, mm): ``experiment``, ``radius_mm``, ``true_x/y/z`` (the
        true bubble-cloud centre); ``centroid_x/y/z``; ``sphere_x/y/z`` and ``sphere_radius_mm`` (the
        zone's least-squares sphere); ``ref_radius_<d>`` along the centre pose's depth/TB/LR axes and
        those axes ``axis_<d>_x/y/z``; the reference's own errors ``ref_err_<d>``,
        ``ref_err_euclidean``, ``ref_radius_err_<d>``, ``sphere_radius_err_mm``; ``clearance_mm`` (the
        sphere to the phantom's faces), ``n_points``, ``volume_mm3``, ``seconds``, ``ok`` and
        ``failure`` (no zone found: NaN, skipped by Table II's means). Pass it to
        :func:`~histostudy.study.pose.metrics.experiment_metrics` (``reference=``).

    Raises:
        TypeError: ``physical`` is not a TransducerModel.
        ValueError: a voxel size not > 0, a blur or noise < 0, ``records`` without the run's columns,
            or records that do not match the set-ups of this config and seed.
    """
    _check_reference_inputs(physical, phantom_voxel_mm, cbct_voxel_mm, cbct_blur_mm, cbct_noise_hu)
    wanted, centres = _wanted_experiments(config, records, experiments)
    rows = []
    for exp, _, _, rng_cbct in draw_experiments(config, seed):
        if wanted is not None and exp.experiment not in wanted:
            continue
        truth = bubble_cloud_centre_mm(physical, exp.T_true["centre"], config.bubble_offset_mm)
        if records is not None:
            _check_records_match(exp, truth, centres)
        row = _experiment_reference(exp, truth, physical=physical, config=config, rng=rng_cbct,
                                    phantom_voxel_mm=phantom_voxel_mm, cbct_voxel_mm=cbct_voxel_mm,
                                    cbct_blur_mm=cbct_blur_mm, cbct_noise_hu=cbct_noise_hu,
                                    treatment_spacing_mm=treatment_spacing_mm, treatment_inset_mm=treatment_inset_mm,
                                    keep_volumes=keep_volumes)
        rows.append(row)
        if row["ok"] and progress:
            progress(f"CBCT reference {exp.experiment + 1}/{config.n_experiments}: centroid "
                     f"{row['ref_err_euclidean']:.2f} mm from the true centre")
    return pd.DataFrame(rows)


def _check_reference_inputs(physical, phantom_voxel_mm, cbct_voxel_mm, cbct_blur_mm, cbct_noise_hu) -> None:
    """Raise unless ``physical`` is a :class:`TransducerModel`, the voxel sizes (mm) are > 0 and
    the CBCT's blur (mm) and noise (HU) are >= 0 (:func:`cbct_reference`'s arguments)."""
    if not isinstance(physical, TransducerModel):
        raise TypeError(f"physical must be a histostudy.transducer.TransducerModel, got {type(physical).__name__}")
    _positive(phantom_voxel_mm, "phantom_voxel_mm")
    _positive(cbct_voxel_mm, "cbct_voxel_mm")
    _positive(cbct_blur_mm, "cbct_blur_mm", allow_zero=True)
    _positive(cbct_noise_hu, "cbct_noise_hu", allow_zero=True)


def _wanted_experiments(config: PoseStudyConfig, records: pd.DataFrame | None,
                        experiments: Sequence[int] | None) -> tuple[set[int] | None, pd.DataFrame | None]:
    """``(wanted, centres)``: the experiment indices to treat (None: all of ``config``), those of
    ``records`` and/or ``experiments``, and the records' centre-pose rows by experiment (their true
    bubble-cloud centres, C-arm mm, and radii ``r``, mm; None without records), after checking
    the records' columns and that their experiments lie within ``config.n_experiments``."""
    wanted = centres = None
    if records is not None:
        need = {"experiment", "position", "radius_mm", "true_x", "true_y", "true_z"}
        if not isinstance(records, pd.DataFrame) or not need <= set(records.columns):
            raise ValueError(f"records must be run_pose_study's rows with columns {sorted(need)}")
        centres = records[records["position"] == "centre"].groupby("experiment").first()
        wanted = set(int(e) for e in records["experiment"].unique())
        beyond = sorted(e for e in wanted if not 0 <= e < config.n_experiments)
        if beyond:
            raise ValueError(f"records hold experiments {beyond} beyond config.n_experiments={config.n_experiments}: "
                             "pass the config and seed the records were made with")
    if experiments is not None:
        chosen = {int(e) for e in experiments}
        wanted = chosen if wanted is None else wanted & chosen
    return wanted, centres


def _check_records_match(exp: PoseExperiment, truth: np.ndarray, centres: pd.DataFrame) -> None:
    """Raise unless the records' true centre (C-arm mm, within 1e-6) and radius ``r`` (mm) of
    ``exp`` are those of the set-up redrawn from the config and seed (``truth``)."""
    got = centres.loc[exp.experiment, ["true_x", "true_y", "true_z"]].to_numpy(float) \
        if exp.experiment in centres.index else None
    if got is None or not np.allclose(got, truth, atol=1e-6) \
            or float(centres.loc[exp.experiment, "radius_mm"]) != exp.radius_mm:
        raise ValueError(f"experiment {exp.experiment}: the records' true centre {got} and radius do not "
                         f"match the set-up redrawn from this config and seed (true centre "
                         f"{truth.round(3).tolist()}, r = {exp.radius_mm} mm): pass the config, seed and "
                         "physical transducer the records were made with")


def _experiment_reference(exp: PoseExperiment, truth: np.ndarray, *, physical: TransducerModel,
                          config: PoseStudyConfig, rng: np.random.Generator, phantom_voxel_mm, cbct_voxel_mm,
                          cbct_blur_mm: float, cbct_noise_hu: float, treatment_spacing_mm, treatment_inset_mm,
                          keep_volumes: bool) -> dict:
    """One row of :func:`cbct_reference`'s table (§II-D, §II-E.3): ``exp`` treated about its true
    centre pose, its post-treatment CBCT simulated and segmented (``rng``: the experiment's CBCT
    draws) and the zone measured against ``truth`` (the true bubble-cloud centre, C-arm mm); a
    NaN row with ``ok`` False and the ``failure`` when nothing is segmented."""
    t0 = time.perf_counter()
    spec, T_cp = phantom_placement(exp.scene)
    axes = transducer_axes(exp.T_true["centre"])
    R = exp.T_true["centre"][:3, :3]
    local = np.linalg.solve(T_cp[:3, :3], truth - T_cp[:3, 3])
    clearance = float(0.5 * spec.size_mm - np.abs(local).max() - exp.radius_mm)
    try:
        seg, post, n_points = _treat_and_scan(exp, spec, T_cp, physical=physical, config=config, rng=rng,
                                              phantom_voxel_mm=phantom_voxel_mm, cbct_voxel_mm=cbct_voxel_mm,
                                              cbct_blur_mm=cbct_blur_mm, cbct_noise_hu=cbct_noise_hu,
                                              treatment_spacing_mm=treatment_spacing_mm,
                                              treatment_inset_mm=treatment_inset_mm)
    except ValueError as exc:  # nothing segmented: the experiment has no reference (NaN), as a lost CBCT
        return _failed_row(exp, truth, clearance, str(exc), t0)
    row = _reference_row(exp, truth, seg, axes, R, clearance=clearance, n_points=n_points, t0=t0)
    if keep_volumes:
        row["_volumes"] = {"post": post, "segmentation": seg, "T_carm_phantom": T_cp}
    return row


def _failed_row(exp: PoseExperiment, truth: np.ndarray, clearance: float, failure: str, t0: float) -> dict:
    """The row of an experiment whose segmentation found no zone: its set-up (true centre, C-arm
    mm; ``r``, clearance, mm), NaN for every measured column, ``ok`` False and the ``failure``;
    ``seconds`` since ``t0`` (:func:`time.perf_counter`)."""
    nan = float("nan")
    return {"experiment": exp.experiment, "radius_mm": exp.radius_mm,
            **{f"true_{a}": v for a, v in zip("xyz", truth)},
            **{c: nan for c in REFERENCE_COLUMNS[1:]},
            **{f"ref_err_{d}": nan for d in (*DIRECTIONS, "euclidean")},
            **{f"ref_radius_err_{d}": nan for d in DIRECTIONS}, "sphere_radius_err_mm": nan,
            "clearance_mm": clearance, "n_points": 0, "volume_mm3": nan,
            "ok": False, "failure": failure, "seconds": time.perf_counter() - t0}


def _reference_row(exp: PoseExperiment, truth: np.ndarray, seg, axes: dict, R: np.ndarray, *, clearance: float,
                   n_points: int, t0: float) -> dict:
    """The row of an experiment with a segmented zone ``seg`` (§II-E.3, C-arm mm): its centroid,
    fitted sphere and radii along the centre pose's depth/TB/LR ``axes`` (``R``'s columns: LR,
    TB, -depth), and their errors against ``truth`` and ``r``; ``seconds`` since ``t0``."""
    radii = dict(zip(("lr", "tb", "depth"), seg.radii_along(R)))  # columns of R: LR, TB, -depth
    err = seg.centroid_mm - truth
    return {"experiment": exp.experiment, "radius_mm": exp.radius_mm,
            **{f"true_{a}": v for a, v in zip("xyz", truth)},
            **{f"centroid_{a}": v for a, v in zip("xyz", seg.centroid_mm)},
            **{f"sphere_{a}": v for a, v in zip("xyz", seg.sphere_centre_mm)},
            "sphere_radius_mm": seg.sphere_radius_mm,
            **{f"ref_radius_{d}": float(radii[d]) for d in DIRECTIONS},
            **{f"axis_{d}_{a}": float(v) for d in DIRECTIONS for a, v in zip("xyz", axes[d])},
            **{f"ref_err_{d}": float(err @ axes[d]) for d in DIRECTIONS},
            "ref_err_euclidean": float(np.linalg.norm(err)),
            **{f"ref_radius_err_{d}": float(radii[d] - exp.radius_mm) for d in DIRECTIONS},
            "sphere_radius_err_mm": float(seg.sphere_radius_mm - exp.radius_mm),
            "clearance_mm": clearance, "n_points": n_points, "volume_mm3": seg.volume_mm3,
            "ok": True, "failure": "", "seconds": time.perf_counter() - t0}


def reference_by_experiment(reference) -> dict:
    """:func:`cbct_reference`'s table by experiment, checked.

    Args:
        reference: :func:`cbct_reference`'s table.

    Returns:
        ``{experiment: row}``.

    Raises:
        TypeError: ``reference`` is not a DataFrame.
        ValueError: it lacks :data:`REFERENCE_COLUMNS` or holds an experiment twice.
    """
    if not isinstance(reference, pd.DataFrame):
        raise TypeError(f"reference must be cbct_reference()'s DataFrame (or None for the ground truth), "
                        f"got {type(reference).__name__}")
    missing = [c for c in REFERENCE_COLUMNS if c not in reference.columns]
    if missing:
        raise ValueError(f"reference lacks the columns {missing}: pass the table cbct_reference() returns")
    if reference["experiment"].duplicated().any():
        raise ValueError("reference holds an experiment twice: one row per experiment expected")
    return {int(r["experiment"]): r for _, r in reference.iterrows()}

