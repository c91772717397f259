"""The paper's set-up pose (§II-D, §II-E): the transducer above the supine patient in a water bath, aimed at
a focal point, as ``T_carm_transducer`` (transducer -> C-arm, mm)."""

from __future__ import annotations

import numpy as np

from histostudy.geometry import make_transform, rotation_about_axis

__all__ = ["pose_facing"]


def pose_facing(direction=(0.0, 1.0, 0.0), focal_point_mm=(0.0, 0.0, 0.0),
                axial_rotation_rad: float = 0.0) -> np.ndarray:
    """``T_carm_transducer`` of a transducer aimed along ``direction`` at ``focal_point_mm``.

    Args:
        direction: world (CBCT, LPS) vector from the transducer centre to the focal point — the
            paper's set-up, transducer above the supine patient in a water bath, is the default
            ``(0, 1, 0)`` (anterior to posterior): the transducer centre then sits at
            ``focal_point + (0, -R, 0)``. A :class:`~histostudy.imaging.carm.View` stands for its beam
            direction: the transducer between source and focal point, facing the detector en face.
        focal_point_mm: world position of the geometric focal point (the transducer origin).
        axial_rotation_rad: rotation about the transducer axis. At 0 the transducer's x (LR) axis
            is the world x axis projected on the aperture plane (world z when the axis is along x),
            so in the default set-up LR is the patient's left and TB (y) points to the head.
    """
    d = np.asarray(getattr(direction, "principal_direction", direction), dtype=np.float64).reshape(-1)
    norm = np.linalg.norm(d)
    if d.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"direction must be a non-zero finite 3-vector or a View, got {direction!r}")
    z = -d / norm
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = ref - ref.dot(z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z]) @ rotation_about_axis([0, 0, 1], float(axial_rotation_rad))
    return make_transform(R, focal_point_mm)
