"""The targeting study's figures: Fig. 7's post-treatment CBCT cuts through the target (§III) and the
inputs of the 3-D scene of the set-up (§II-C, §II-D, Fig. 2).

Volumes and points are in the C-arm frame (LPS, mm); the 3-D render itself is
:func:`histostudy.reporting.targeting_scene` (a higher layer), which :func:`scene_figure` feeds.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd

from histostudy.imaging import Volume
from histostudy.transducer import TransducerModel
from histostudy.treatment import ZoneSegmentation

from ._positioning import scene_at_target

__all__ = ["SceneFigure", "fig7_figures", "plot_target_slices", "scene_figure"]


def plot_target_slices(volume: Volume, segmentation: ZoneSegmentation | None, target_mm, *, title: str = "",
                       half_width_mm: float = 30.0):
    """Fig. 7: transverse, frontal and sagittal slices of a CBCT through the target, the target as a
    green dot and the segmented zone's outline in blue.

    Args:
        volume: the CBCT (HU, C-arm frame).
        segmentation: the treated zone's segmentation; None: the slices and the target only (e.g. a
            pre-treatment CBCT).
        target_mm: the target (3, C-arm frame, mm).
        title: the figure's title.
        half_width_mm: half the width shown about the target (mm).

    Returns:
        The matplotlib figure.

    Raises:
        ValueError: the target outside the volume, or a mask of another shape than the volume.
    """
    import matplotlib.pyplot as plt

    target = np.asarray(target_mm, dtype=np.float64).reshape(3)
    if not volume.contains(target)[0]:
        raise ValueError(f"target_mm={target.round(2).tolist()} lies outside the volume")
    i, j, k = np.round(volume.world_to_voxel(target)[0]).astype(int)
    x, y, z = volume.axes_mm()
    mask = np.zeros(volume.data.shape, bool) if segmentation is None else segmentation.mask
    if mask.shape != volume.data.shape:
        raise ValueError(f"segmentation mask {mask.shape} does not match the volume {volume.data.shape}")
    # (name, image rows x cols, row axis, col axis, target (col, row), row/col labels)
    cuts = ((f"transverse (z = {z[k]:.1f} mm)", volume.data[k], mask[k], y, x, (target[0], target[1]),
             "y (P) mm", "x (L) mm"),
            (f"frontal (y = {y[j]:.1f} mm)", volume.data[:, j, :], mask[:, j, :], z, x, (target[0], target[2]),
             "z (S) mm", "x (L) mm"),
            (f"sagittal (x = {x[i]:.1f} mm)", volume.data[:, :, i], mask[:, :, i], z, y, (target[1], target[2]),
             "z (S) mm", "y (P) mm"))
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    lo, hi = np.percentile(volume.data, [1, 99.5])
    for ax, (name, img, m, rows, cols, (tc, tr), rlab, clab) in zip(axes, cuts):
        extent = (cols[0], cols[-1], rows[0], rows[-1])
        ax.imshow(img, cmap="gray", vmin=lo, vmax=hi, origin="lower", extent=extent, interpolation="nearest")
        if m.any():
            ax.contour(cols, rows, m.astype(float), levels=[0.5], colors="tab:blue", linewidths=1.2)
        ax.plot(tc, tr, "o", color="lime", markersize=6, markeredgecolor="k")
        ax.set_xlim(tc - half_width_mm, tc + half_width_mm)
        # Transverse: anterior (-y, where the transducer is) at the top, as radiology shows it.
        flip = rlab.startswith("y")
        ax.set_ylim((tr + half_width_mm, tr - half_width_mm) if flip else (tr - half_width_mm, tr + half_width_mm))
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(clab)
        ax.set_ylabel(rlab)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig



def fig7_figures(records: pd.DataFrame, volumes: pd.Series, n_experiments: int) -> Iterator[tuple[str, object, str]]:
    """Fig. 7 for the first experiments of the first robot, one figure at a time (each made when asked for).

    Args:
        records: the study's rows.
        volumes: their ``"_volumes"`` column (a study run with ``keep_volumes``).
        n_experiments: the experiments shown.

    Returns:
        An iterator of ``(name, figure, caption)``.
    """
    first = records.index[records["robot"] == records["robot"].iloc[0]]
    for idx in first[:n_experiments]:
        v = volumes[idx]
        r = records.loc[idx]
        fig = plot_target_slices(v["post"], v["segmentation"], v["target"],
                                 title=f"experiment {r.experiment}: {r.diameter_mm:.0f} mm zone, "
                                       f"error {r.err_euclidean:.2f} mm")
        yield (f"fig7_experiment_{int(r.experiment)}", fig,
               f"Fig. 7: experiment {int(r.experiment)}, target (green) and segmented zone (blue) in the "
               "post-treatment CBCT")


@dataclass(frozen=True)
class SceneFigure:
    """The 3-D scene of one experiment: its figure name and caption, and ``scene``, the keyword
    arguments of :func:`histostudy.reporting.targeting_scene` but the views."""

    name: str
    caption: str
    scene: dict


def scene_figure(records: pd.DataFrame, volumes: pd.Series, physical: TransducerModel,
                 seed: np.random.SeedSequence) -> SceneFigure:
    """The first experiment's 3-D scene at the treatment pose: the true base and the true physical
    transducer on the flange (:func:`~histostudy.study.targeting._positioning.scene_at_target`), the
    phantom, the target and the segmented zone's fitted sphere.

    Args:
        records: the study's rows.
        volumes: their ``"_volumes"`` column.
        physical: the physical transducer drawn.
        seed: seeds the transducer's point sampling in the render.

    Returns:
        The :class:`SceneFigure`: its name, caption and the keyword arguments of
        :func:`histostudy.reporting.targeting_scene` but the views.
    """
    idx = records.index[records["robot"] == records["robot"].iloc[0]][0]
    v = volumes[idx]
    seg = v["segmentation"]
    at_target = scene_at_target(v["truth"], v["calibration"], v["target"], v["R_des"])
    experiment = int(records.loc[idx, "experiment"])
    scene = dict(T_carm_base=at_target["T_carm_base"], joints_rad=at_target["joints_rad"], model=physical,
                 T_carm_transducer=at_target["T_carm_transducer"], rng=np.random.default_rng(seed),
                 T_carm_phantom=at_target["T_carm_phantom"], target_mm=v["target"],
                 zone_centre_mm=seg.sphere_centre_mm, zone_radius_mm=seg.sphere_radius_mm)
    caption = (f"Experiment {experiment} in the C-arm frame: C-arm planes A (red) and B (blue), the UR5e at the "
               "treatment pose, the physical transducer, the phantom, the target (green) and the segmented "
               "treated zone (cyan sphere); right: close-up")
    return SceneFigure(f"scene_3d_experiment_{experiment}", caption, scene)
