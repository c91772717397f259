"""Where the transducer sits in notebook 04's experiments and which way its errors point (§II-D,
§II-E.3): the error directions depth/TB/LR (the transducer's ``-z``, ``y``, ``x``), the six margin
poses, the experiments' and the sweeps' random poses. C-arm (CBCT) frame, mm and radians unless a
name says deg (docs/pose-study.md).
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
    """World unit vectors of §II-E's error directions for a pose.

    Args:
        T_carm_transducer: the pose (4x4, mm; transducer -> C-arm).

    Returns:
        ``{"depth": -z, "tb": y, "lr": x}``: the transducer's axes in the C-arm frame, each (3,).
    """
    R = np.asarray(T_carm_transducer, dtype=np.float64)[:3, :3]
    return {"depth": -R[:, 2], "tb": R[:, 1], "lr": R[:, 0]}


def margin_positions(T_centre, radius_mm: float) -> dict[str, np.ndarray]:
    """The centre pose and the six margin poses of §II-D: the transducer translated by ``radius_mm``
    along the robot's axes (here the transducer's own LR/TB/depth axes at the centre pose).

    Args:
        T_centre: the centre pose ``T_carm_transducer`` (4x4, mm).
        radius_mm: the treatment radius ``r`` (mm).

    Returns:
        ``{"centre", "top", "bottom", "left", "right", "front", "back"}`` -> pose (4x4, mm), in that
        order (:data:`MARGINS`).
    """
    axes = transducer_axes(T_centre)
    out = {"centre": np.array(T_centre, dtype=np.float64)}
    for name, (direction, sign) in MARGINS.items():
        T = out["centre"].copy()
        T[:3, 3] += sign * radius_mm * axes[direction]
        out[name] = T
    return out


def experiment_pose(rng: np.random.Generator, config, centre_mm) -> np.ndarray:
    """An experiment's commanded centre pose ``T_carm_transducer``: the transducer axis tilted from
    vertical, the focal point jittered about ``centre_mm``, a uniform turn about the axis.

    The draws (two tilts, three jitters, one turn) keep this order: every seeded study result
    depends on it.

    Args:
        rng: the stream drawn from.
        config: a :class:`~histostudy.study.pose.experiments.PoseStudyConfig` (or anything with
            ``tilt_sd_deg``, the tilt's SD per axis in deg, and ``focal_jitter_mm``, the focal
            point's uniform half-range per axis in mm).
        centre_mm: the phantom centre (C-arm frame, mm).

    Returns:
        The pose (4x4, mm; transducer -> C-arm).
    """
    tilt = np.deg2rad(config.tilt_sd_deg)
    direction = (np.tan(rng.normal(0, tilt)), 1.0, np.tan(rng.normal(0, tilt)))
    focal = np.asarray(centre_mm, float) + rng.uniform(-config.focal_jitter_mm, config.focal_jitter_mm, 3)
    return pose_facing(direction, focal, rng.uniform(0, 2 * np.pi))


def bubble_cloud_centre_mm(physical: TransducerModel, T_carm_transducer, offset_mm) -> np.ndarray:
    """World position of the bubble cloud for a pose: the physical transducer's acoustic focal point
    plus ``offset_mm``, mapped by ``T_carm_transducer``.

    Args:
        physical: the physical transducer model.
        T_carm_transducer: the pose (4x4, mm; transducer -> C-arm).
        offset_mm: the bubble cloud's offset from the focal point (3, transducer frame, mm).

    Returns:
        The centre (3, C-arm frame, mm).
    """
    local = np.asarray(physical.focal_point_mm, float) + np.asarray(offset_mm, float)
    return T_carm_transducer[:3, :3] @ local + T_carm_transducer[:3, 3]


def axial_symmetric_rotation_error_deg(T_estimate, T_true) -> float:
    """Rotation error between two poses, up to a half turn about the transducer axis.

    The aperture, quadrant gaps and cutout are symmetric under a half turn about the axis, and
    §II-B.4's axial search covers [0, 180 deg) only: a half-turn flip moves no focal point.

    Args:
        T_estimate: the estimated pose (4x4, mm; transducer -> C-arm).
        T_true: the true pose (4x4, mm).

    Returns:
        The smaller of the two rotation angles (deg).
    """
    R_est = np.asarray(T_estimate, dtype=np.float64)[:3, :3]
    R_true = np.asarray(T_true, dtype=np.float64)[:3, :3]
    return float(min(np.rad2deg(rotation_angle(R_est.T @ R_true)),
                     np.rad2deg(rotation_angle((R_est @ HALF_TURN).T @ R_true))))


def rotation_error_modulo_symmetry_deg(T_estimate, T_true, *, half_turn: bool) -> tuple[float, bool]:
    """The rotation error between two poses and whether the estimate is nearer the half-turned truth.

    Args:
        T_estimate: the estimated pose (4x4, mm; transducer -> C-arm).
        T_true: the true pose (4x4, mm).
        half_turn: the model looks the same after a half turn about its axis
            (:func:`histostudy.transducer.half_turn_symmetric`): the error is taken up to that turn
            (:func:`axial_symmetric_rotation_error_deg`); otherwise plainly.

    Returns:
        ``(error_deg, half_turned)``.
    """
    R_est = np.asarray(T_estimate, dtype=np.float64)[:3, :3]
    R_true = np.asarray(T_true, dtype=np.float64)[:3, :3]
    plain = float(np.rad2deg(rotation_angle(R_est.T @ R_true)))
    turned = float(np.rad2deg(rotation_angle((R_est @ HALF_TURN).T @ R_true)))
    return (min(plain, turned) if half_turn else plain), turned < plain


def random_pose_in_views(rng: np.random.Generator, views: Sequence[View], *, translation_mm: float = 100.0,
                         visible_points_mm=((0.0, 0.0, 0.0),), max_tries: int = 1000) -> np.ndarray:
    """A pose in the paper's training ranges (§II-B.2: Euler angles in [0, 360) deg, translations
    within ± ``translation_mm`` per axis) whose ``visible_points_mm`` all project onto every
    detector, in front of the source (rejection sampling).

    Args:
        rng: the stream drawn from.
        views: the C-arm views.
        translation_mm: the translations' half-range per axis (mm).
        visible_points_mm: transducer-frame points (n, 3, mm; default the focal point).
        max_tries: draws before giving up.

    Returns:
        The pose ``T_carm_transducer`` (4x4, mm).

    Raises:
        RuntimeError: no draw of ``max_tries`` shows the points in every view.
    """
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
    """The transducer-frame points a random pose of the sweeps must show in every view.

    Args:
        pose_model: the digital transducer model.

    Returns:
        ``(2, 3)`` (mm): the focal point and the transducer's centre (the centroid of the model's
        element points).
    """
    centre = np.mean(pose_model.points[Feature.TRANSDUCER], axis=0)
    return np.stack([np.asarray(pose_model.focal_point_mm, float), centre])

