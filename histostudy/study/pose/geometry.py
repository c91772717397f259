"""Where the transducer sits in notebook 04's experiments and which way its errors point (§II-D, §II-E.3).

C-arm (CBCT) frame, mm and radians unless a name says deg. The error directions of §II-E are
the transducer's own axes: depth (the direction of ultrasound propagation, the transducer's
``-z``), top-bottom TB (``y``) and left-right LR (``x``). Each experiment moves the transducer
by the treatment radius ``r`` along them to the six margin points of §II-D. The random poses of
the sweeps are drawn in the paper's training ranges (§II-B.2).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from histostudy.geometry import make_transform, matrix_from_euler, rotation_angle
from histostudy.imaging import View
from histostudy.transducer import HALF_TURN, Feature, TransducerModel, pose_facing

__all__ = [
    "DIRECTIONS",
    "MARGINS",
    "axial_symmetric_rotation_error_deg",
    "rotation_error_modulo_symmetry_deg",
    "bubble_cloud_centre_mm",
    "experiment_pose",
    "margin_positions",
    "random_pose_in_views",
    "sweep_visible_points",
    "transducer_axes",
]

#: Error directions of §II-E: name -> column of the direction matrix (see :func:`transducer_axes`).
DIRECTIONS = ("depth", "tb", "lr")

#: Margin points: name -> (direction, sign). Paper: top, bottom, left, right, front, back.
MARGINS = {
    "top": ("tb", +1), "bottom": ("tb", -1),
    "left": ("lr", +1), "right": ("lr", -1),
    "front": ("depth", +1), "back": ("depth", -1),
}


def transducer_axes(T_carm_transducer) -> dict[str, np.ndarray]:
    """World unit vectors of §II-E's directions for a pose: depth (propagation, ``-z``), TB (``y``), LR (``x``)."""
    R = np.asarray(T_carm_transducer, dtype=np.float64)[:3, :3]
    return {"depth": -R[:, 2], "tb": R[:, 1], "lr": R[:, 0]}


def margin_positions(T_centre, radius_mm: float) -> dict[str, np.ndarray]:
    """The centre pose and the six margin poses: the transducer translated by ``radius_mm`` along
    the robot's axes (here the transducer's own LR/TB/depth axes at the centre pose)."""
    axes = transducer_axes(T_centre)
    out = {"centre": np.array(T_centre, dtype=np.float64)}
    for name, (direction, sign) in MARGINS.items():
        T = out["centre"].copy()
        T[:3, 3] += sign * radius_mm * axes[direction]
        out[name] = T
    return out


def experiment_pose(rng: np.random.Generator, config, centre_mm) -> np.ndarray:
    """An experiment's commanded centre pose ``T_carm_transducer``: the transducer axis tilted from
    vertical by ``config.tilt_sd_deg`` (SD per axis), the focal point uniform within
    ``± config.focal_jitter_mm`` of ``centre_mm`` (world mm) per axis, a uniform turn about the axis.

    ``config``: a :class:`~histostudy.study.pose._config.PoseStudyConfig` (or anything with those two
    attributes). The draws (two tilts, three jitters, one turn) keep
    this order: every seeded study result depends on it.
    """
    tilt = np.deg2rad(config.tilt_sd_deg)
    direction = (np.tan(rng.normal(0, tilt)), 1.0, np.tan(rng.normal(0, tilt)))
    focal = np.asarray(centre_mm, float) + rng.uniform(-config.focal_jitter_mm, config.focal_jitter_mm, 3)
    return pose_facing(direction, focal, rng.uniform(0, 2 * np.pi))


def bubble_cloud_centre_mm(physical: TransducerModel, T_carm_transducer, offset_mm) -> np.ndarray:
    """World position (mm) of the bubble cloud for a pose: the physical transducer's acoustic focal
    point plus ``offset_mm`` (transducer frame), mapped by ``T_carm_transducer``."""
    local = np.asarray(physical.focal_point_mm, float) + np.asarray(offset_mm, float)
    return T_carm_transducer[:3, :3] @ local + T_carm_transducer[:3, 3]


def axial_symmetric_rotation_error_deg(T_estimate, T_true) -> float:
    """Rotation error (deg) between two poses, up to a half turn about the transducer axis.

    The aperture, quadrant gaps and cutout are symmetric under a half turn about the axis, and
    §II-B.4's axial search covers [0, 180 deg) only: a half-turn flip moves no focal point.
    """
    R_est = np.asarray(T_estimate, dtype=np.float64)[:3, :3]
    R_true = np.asarray(T_true, dtype=np.float64)[:3, :3]
    return float(min(np.rad2deg(rotation_angle(R_est.T @ R_true)),
                     np.rad2deg(rotation_angle((R_est @ HALF_TURN).T @ R_true))))


def rotation_error_modulo_symmetry_deg(T_estimate, T_true, *, half_turn: bool) -> tuple[float, bool]:
    """``(error_deg, half_turned)``: the rotation error between two poses (deg) and whether the
    estimate is nearer the half-turned truth. With ``half_turn`` (the model looks the same after a
    half turn about its axis, :func:`histostudy.transducer.half_turn_symmetric`) the error is taken
    up to that turn (:func:`axial_symmetric_rotation_error_deg`); without it, plainly."""
    R_est = np.asarray(T_estimate, dtype=np.float64)[:3, :3]
    R_true = np.asarray(T_true, dtype=np.float64)[:3, :3]
    plain = float(np.rad2deg(rotation_angle(R_est.T @ R_true)))
    turned = float(np.rad2deg(rotation_angle((R_est @ HALF_TURN).T @ R_true)))
    return (min(plain, turned) if half_turn else plain), turned < plain


def random_pose_in_views(rng: np.random.Generator, views: Sequence[View], *, translation_mm: float = 100.0,
                         visible_points_mm=((0.0, 0.0, 0.0),), max_tries: int = 1000) -> np.ndarray:
    """A pose in the paper's training ranges (§II-B.2: Euler angles in [0, 360) deg, translations
    in ±10 cm per axis) whose ``visible_points_mm`` (transducer frame; default the focal point)
    all project onto every detector, in front of the source (rejection sampling)."""
    local = np.asarray(visible_points_mm, dtype=np.float64).reshape(-1, 3)
    for _ in range(max_tries):
        R = matrix_from_euler(rng.uniform(0, 2 * np.pi, 3), "xyz")
        t = rng.uniform(-translation_mm, translation_mm, 3)
        world = local @ R.T + t
        if all(np.all(v.in_image(v.project(world))) and np.all(v.project_homogeneous(world)[:, 2] > 0)
               for v in views):
            return make_transform(R, t)
    raise RuntimeError(f"no pose with {len(local)} given point(s) in every view after {max_tries} draws")


def sweep_visible_points(pose_model: TransducerModel) -> np.ndarray:
    """``(2, 3)`` transducer-frame points a random pose of the sweeps must show in every view: the
    focal point and the transducer's centre (the centroid of the model's element points)."""
    centre = np.mean(pose_model.points[Feature.TRANSDUCER], axis=0)
    return np.stack([np.asarray(pose_model.focal_point_mm, float), centre])

