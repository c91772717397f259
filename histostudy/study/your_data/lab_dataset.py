"""A small lab-like dataset, generated: what a lab hands the workflow of ``histostudy.lab`` (DICOM XA
stations and cine, flange poses, a NIfTI CBCT, STL meshes), with the synthetic truth a lab never has
kept beside it (§II-A to §II-D). The layout and how it is drawn: docs/study-sections.md, "06".
"""

from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from histostudy.core import atomic_write_json, to_jsonable
from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.imaging import (
    PhantomSpec,
    View,
    add_poisson_noise,
    background_line_integrals,
    check_target,
    default_biplane,
    detector_counts,
    random_background,
    random_target,
    render_line_integrals,
    save_views,
    save_volume_nifti,
    simulate_cbct,
    write_xa,
)
from histostudy.robot import forward_kinematics, pose_from_transform
from histostudy.transducer import TransducerModel, export_meshes

from ..targeting import calibration_poses, phantom_for
from ..targeting.setup import TargetingStudyConfig, draw_ground_truth, start_joints

__all__ = ["LabDataset", "LabScene", "write_lab_dataset"]

DATASET_FORMAT = "histostudy.lab_dataset/1"


class _FrameSettings(Protocol):
    """The frames' dose and splatting, as :meth:`~histostudy.imaging.FrameRenderConfig.frame_kwargs` gives them."""

    def frame_kwargs(self) -> dict: ...


@dataclass(frozen=True, eq=False)
class LabScene:
    """What the lab-like frames are rendered from: the physical transducer (quadrants moved, §IV)
    splatted over the phantom scene's exact line integrals (``backgrounds``, one ``(rows, cols)``
    array per view, computed once: the scene does not move), on ``views``, with the study's dose
    and splatting (``settings``: :class:`~histostudy.imaging.FrameRenderConfig`, e.g. a
    :class:`histostudy.study.targeting.setup.TargetingStudyConfig`).

    :meth:`draw` makes one from two Generators; :meth:`render_pair` renders the biplane images of a
    pose. :func:`write_lab_dataset` and :mod:`.moving_cine` render through it.

    Args:
        views: the biplane views.
        physical: the physical transducer model.
        backgrounds: the scene's line integrals, one ``(rows, cols)`` array per view.
        settings: the dose and splatting (anything with ``frame_kwargs()``).
    """

    views: tuple
    physical: TransducerModel
    backgrounds: tuple
    settings: _FrameSettings

    @classmethod
    def draw(cls, settings: _FrameSettings, views, *, rng_scene: np.random.Generator, rng_physical: np.random.Generator,
             render_spacing_mm: float = 0.25) -> LabScene:
        """The scene of ``settings`` (its ``frame_kwargs``) on ``views``: the phantom scene drawn from
        ``rng_scene``, the physical transducer's deviations from ``rng_physical``, sampled at
        ``render_spacing_mm`` (mm)."""
        if not (np.isfinite(render_spacing_mm) and render_spacing_mm > 0):
            raise ValueError(f"render_spacing_mm must be a finite spacing > 0 mm, got {render_spacing_mm!r}")
        physical = TransducerModel.build_physical(spacing_mm=render_spacing_mm, rng=rng_physical)
        scene = random_background(rng_scene, "phantom")
        views = tuple(views)
        return cls(views, physical, tuple(background_line_integrals(scene, v) for v in views), settings)

    def render_pair(self, T_carm_transducer, rng: np.random.Generator) -> list[np.ndarray]:
        """The line-integral image (``(rows, cols)`` float32) of each view with the transducer at
        ``T_carm_transducer`` (4x4, mm, C-arm frame): the image of
        :func:`~histostudy.imaging.render_frame` with ``physical`` and the scene, the same draws from
        ``rng`` (splat jitter, then photon noise, view after view), without its labels."""
        kwargs = self.settings.frame_kwargs()
        photons = kwargs.pop("photons_per_pixel")
        out = []
        for view, back in zip(self.views, self.backgrounds):
            image = back + render_line_integrals(self.physical, T_carm_transducer, view, rng=rng,
                                                 **kwargs).astype(np.float64)
            if photons is not None:
                image = add_poisson_noise(image, photons, rng)
            out.append(image.astype(np.float32))
        return out


@dataclass(frozen=True)
class LabDataset:
    """Where :func:`write_lab_dataset` put each file (paths), and the suggested target.

    Args:
        folder: the dataset's folder.
        views: ``views.json``.
        calibration_frames: ``((A.dcm, B.dcm), ...)``, one pair per station.
        flange_poses: ``calibration/flange_poses.json``.
        cine: ``(A.dcm, B.dcm)``.
        cbct: ``cbct.nii.gz``.
        transducer_meshes: the STL files, one per feature class.
        manifest: ``dataset.json``.
        truth: ``truth.json``.
        target_mm: the suggested target (x, y, z), C-arm frame, mm.
        n_cine_frames: the cine's frames.
    """

    folder: Path
    views: Path
    calibration_frames: tuple  # ((A.dcm, B.dcm), ...) per station
    flange_poses: Path
    cine: tuple  # (A.dcm, B.dcm)
    cbct: Path
    transducer_meshes: tuple
    manifest: Path
    truth: Path
    target_mm: np.ndarray
    n_cine_frames: int


def _cine_flange_poses(start_flange: np.ndarray, n: int, step_mm: float, turn_deg: float,
                       rng: np.random.Generator) -> list[np.ndarray]:
    """Flange poses of a slow robot move: a straight line of ``step_mm`` per frame in a random
    horizontal direction (base x-y), with a turn of ``turn_deg`` per frame about a random axis."""
    phi = rng.uniform(0, 2 * np.pi)
    direction = np.array([np.cos(phi), np.sin(phi), 0.0])
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    out = []
    for k in range(n):
        R = matrix_from_rotvec(np.radians(turn_deg * k) * axis) @ start_flange[:3, :3]
        out.append(make_transform(R, start_flange[:3, 3] + step_mm * k * direction))
    return out


def write_lab_dataset(folder: str | os.PathLike, *, seed: int = 20231125, n_cine_frames: int = 4,
                      frame_time_ms: float = 66.7, cine_step_mm: float = 0.5, cine_turn_deg: float = 0.2,
                      config: TargetingStudyConfig | None = None, render_spacing_mm: float = 0.25,
                      views: tuple[View, View] | None = None) -> LabDataset:
    """Write the lab-like dataset (docs/study-sections.md, "06") into ``folder``.

    Args:
        folder: where to write (created; files of the same names are replaced).
        seed: every draw (one ``numpy.random.SeedSequence``): the same seed writes the same files.
        n_cine_frames: the cine's frames (>= 1).
        frame_time_ms: the time between cine frames, ms (> 0).
        cine_step_mm: the flange's move per cine frame, mm (>= 0).
        cine_turn_deg: its turn per cine frame, deg (>= 0).
        config: the set-up's parameters (default: the targeting study's standard ones, phantom
            background, 4 calibration stations).
        render_spacing_mm: the rendered transducer's point spacing, mm (the study renders at 0.125
            mm; 0.25 mm draws fewer points and is enough for 0.3 mm pixels at the isocentre).
        views: the biplane (default :func:`histostudy.imaging.default_biplane`).

    Returns:
        The :class:`LabDataset` of the files written.

    Raises:
        ValueError: a bad ``seed``, ``n_cine_frames``, ``frame_time_ms``, ``cine_step_mm``,
            ``cine_turn_deg`` or ``render_spacing_mm``.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if isinstance(n_cine_frames, bool) or not isinstance(n_cine_frames, (int, np.integer)) or n_cine_frames < 1:
        raise ValueError(f"n_cine_frames must be an integer >= 1, got {n_cine_frames!r}")
    for name, value in (("frame_time_ms", frame_time_ms), ("cine_step_mm", cine_step_mm),
                        ("cine_turn_deg", cine_turn_deg)):
        if not (np.isfinite(value) and value >= 0) or (name == "frame_time_ms" and value <= 0):
            raise ValueError(f"{name} must be finite and {'> 0' if name == 'frame_time_ms' else '>= 0'}, "
                             f"got {value!r}")
    config = TargetingStudyConfig(n_experiments=1, background="phantom") if config is None else config
    biplane = tuple(default_biplane() if views is None else views)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)

    s_truth, s_pose, s_scene, s_render, s_physical, s_cine, s_target, s_cbct = np.random.SeedSequence(seed).spawn(8)
    truth = draw_ground_truth(np.random.default_rng(s_truth), config)
    scene = LabScene.draw(config, biplane, rng_scene=np.random.default_rng(s_scene),
                          rng_physical=np.random.default_rng(s_physical), render_spacing_mm=render_spacing_mm)
    render_model, physical = TransducerModel.build(spacing_mm=render_spacing_mm), scene.physical
    rng_render = np.random.default_rng(s_render)
    when = _dt.datetime(2023, 1, 19, 10, 0, 0)

    def render_pair(T_carm_transducer):
        return scene.render_pair(T_carm_transducer, rng_render)

    # The calibration stations: single-frame pairs, the flange poses as the robot reports them.
    flanges = calibration_poses(np.random.default_rng(s_pose), config, truth)
    stations, true_station_poses = [], []
    for k, F in enumerate(flanges):
        T_true = truth.T_carm_transducer(F)
        true_station_poses.append(T_true)
        paths = []
        for view, image in zip(biplane, render_pair(T_true)):
            paths.append(write_xa(out / "calibration" / f"station_{k}" / f"{view.name}.dcm", view,
                                  detector_counts(image), uid_seed=f"lab-{seed}-station-{k}",
                                  study_uid_seed=f"lab-{seed}", acquisition_time=when + _dt.timedelta(minutes=k)))
        stations.append(tuple(paths))
    flange_file = atomic_write_json(out / "calibration" / "flange_poses.json", to_jsonable({
        "T_base_flange": flanges, "ur_pose": [pose_from_transform(F) for F in flanges],
        "units": {"T_base_flange": "mm", "ur_pose": "m, axis-angle rad"}}))

    # The cine: the robot moving slowly from where the operator jogged it over the phantom.
    start_flange = forward_kinematics(start_joints(truth))
    cine_flanges = _cine_flange_poses(start_flange, n_cine_frames, cine_step_mm, cine_turn_deg,
                                      np.random.default_rng(s_cine))
    true_cine_poses = [truth.T_carm_transducer(F) for F in cine_flanges]
    per_view = [render_pair(T) for T in true_cine_poses]
    cine_start = when + _dt.timedelta(minutes=len(flanges) + 1)
    cine = tuple(write_xa(out / "cine" / f"{view.name}.dcm", view,
                          detector_counts(np.stack([pair[i] for pair in per_view])),
                          uid_seed=f"lab-{seed}-cine", study_uid_seed=f"lab-{seed}", frame_time_ms=frame_time_ms,
                          acquisition_time=cine_start)
                 for i, view in enumerate(biplane))

    # The pre-treatment CBCT of the phantom, and a target inside it with a 12.5 mm zone around it.
    phantom, _ = phantom_for(truth, config)
    cbct = simulate_cbct(phantom, np.random.default_rng(s_cbct), blur_sigma_mm=config.cbct_blur_mm,
                         noise_sd_hu=config.cbct_noise_hu, voxel_mm=config.cbct_voxel_mm)
    cbct_path = save_volume_nifti(cbct, out / "cbct.nii.gz")
    target = check_target(random_target(np.random.default_rng(s_target), PhantomSpec(), truth.T_carm_phantom,
                                        border_mm=16.5), PhantomSpec(), truth.T_carm_phantom, volume=cbct,
                          margin_mm=12.5)

    meshes = tuple(export_meshes(render_model.spec, out / "transducer").values())
    views_path = save_views(out / "views.json", biplane)
    truth_path = atomic_write_json(out / "truth.json", to_jsonable({
        "note": "the synthetic truth, which a lab never has: for measuring errors only",
        "T_carm_base": truth.T_carm_base, "T_flange_transducer": truth.T_flange_transducer,
        "T_carm_phantom": truth.T_carm_phantom, "physical_focal_point_mm": physical.focal_point_mm,
        "station_T_carm_transducer": true_station_poses, "cine_T_carm_transducer": true_cine_poses,
        "cine_T_base_flange": cine_flanges, "cine_start_joints_rad": start_joints(truth)}))
    manifest = atomic_write_json(out / "dataset.json", to_jsonable({
        "format": DATASET_FORMAT, "seed": int(seed),
        "what": "a lab-like dataset generated by histostudy.study.write_lab_dataset: synthetic frames of the "
                "physical transducer model standing in for a lab's C-arm, CBCT, transducer CAD and robot",
        "views": "views.json", "calibration_stations": [[str(p.relative_to(out)) for p in s] for s in stations],
        "flange_poses": str(flange_file.relative_to(out)), "cine": [str(p.relative_to(out)) for p in cine],
        "n_cine_frames": int(n_cine_frames), "frame_time_ms": float(frame_time_ms),
        "cbct": str(cbct_path.relative_to(out)), "transducer_meshes": [str(Path(p).relative_to(out)) for p in meshes],
        "suggested_target_mm": target, "truth": "truth.json"}))
    return LabDataset(folder=out, views=views_path, calibration_frames=tuple(stations), flange_poses=flange_file,
                      cine=cine, cbct=cbct_path, transducer_meshes=meshes, manifest=manifest, truth=truth_path,
                      target_mm=target, n_cine_frames=int(n_cine_frames))
