"""Notebook 01: the digital transducer model (§II-B.1) and synthetic biplane projections (§II-B.2).

Measures the built models (point counts per class, the cap's sphere fit, aperture and cutout
sizes) so that the report sets measured geometry beside the paper's numbers, tabulates the label
content of rendered frames, and times the renderer.
"""

from __future__ import annotations

import time
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from histostudy.geometry import fit_sphere
from histostudy.imaging import render_frame, render_line_integrals
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel

__all__ = ["label_fraction_table", "model_geometry", "point_count_table", "render_timing"]


def point_count_table(models: Mapping[str, TransducerModel]) -> pd.DataFrame:
    """Points per feature class (rows) for each model (columns, e.g. ``"0.47 mm"``), with a total."""
    data = {name: [len(m.points[k]) for k in FEATURE_CLASSES] for name, m in models.items()}
    table = pd.DataFrame(data, index=[k.name.lower() for k in FEATURE_CLASSES])
    table.loc["total"] = table.sum()
    table.index.name = "feature class"
    return table.reset_index()


def model_geometry(model: TransducerModel) -> dict:
    """Geometry measured on the built points (mm): cap sphere fit, aperture widths, cutout diameter.

    The cap is every point on the spherical surface (elements and the boundary bands): points
    whose distance from the focal point is the cap radius to within half a grid step.
    """
    spec = model.spec
    surface = []
    for k in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.GAPS):
        pts = model.points[k]
        r = np.linalg.norm(pts, axis=1)
        surface.append(pts[np.abs(r - spec.radius_mm) <= 0.5 * model.spacing_mm + 1e-9])
    surface = np.vstack(surface)
    centre, radius = fit_sphere(model.points[Feature.TRANSDUCER])
    radial_xy = np.hypot(surface[:, 0], surface[:, 1])
    return {
        "sphere_radius_mm": radius,
        "sphere_centre_mm": centre,
        "aperture_x_mm": float(np.ptp(surface[:, 0])),
        "aperture_y_mm": float(np.ptp(surface[:, 1])),
        "cutout_diameter_mm": float(2.0 * radial_xy.min()),
        "cap_depth_mm": float(np.ptp(surface[:, 2])),
    }


def label_fraction_table(frames: Sequence) -> pd.DataFrame:
    """Pixels per label class in each frame's reference labels (count and percent of the image)."""
    rows = []
    for frame in frames:
        counts = np.bincount(frame.labels.ravel(), minlength=len(Feature))
        for k in Feature:
            rows.append({"view": frame.view.name, "class": k.name.lower(), "pixels": int(counts[k]),
                         "percent": 100.0 * counts[k] / frame.labels.size})
    return pd.DataFrame(rows)


def render_timing(model: TransducerModel, T_carm_transducer, view, *, background, physical=None,
                  repeats: int = 1, seed: int = 0, **render_kwargs) -> pd.DataFrame:
    """Wall time (s) of the stages of one synthetic frame, the median over ``repeats``.

    Stages: the background's projection, the transducer's splatting (:func:`render_line_integrals`)
    and the whole :func:`render_frame` (splatting, labels, background, noise).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    stages = {"background projection": [], "transducer splatting": [], "frame, background precomputed": []}
    image_model = physical if physical is not None else model
    splat_kwargs = {k: v for k, v in render_kwargs.items() if k in ("n_splats", "splat_sigma_mm")}
    for i in range(repeats):
        rng = np.random.default_rng(seed + i)
        t0 = time.perf_counter()
        bg = background.line_integrals(view) if hasattr(background, "line_integrals") else background
        stages["background projection"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        render_line_integrals(image_model, T_carm_transducer, view, rng=rng, **splat_kwargs)
        stages["transducer splatting"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        render_frame(model, T_carm_transducer, view, rng=rng, physical=physical, background=bg, **render_kwargs)
        stages["frame, background precomputed"].append(time.perf_counter() - t0)
    n_points = sum(len(p) for p in image_model.points.values())
    table = pd.DataFrame([{"stage": name, "median_s": float(np.median(t)), "repeats": len(t),
                           "points": n_points if name != "background projection" else pd.NA,
                           "detector": f"{view.shape[1]}x{view.shape[0]}"} for name, t in stages.items()])
    return table.astype({"points": "Int64"})
