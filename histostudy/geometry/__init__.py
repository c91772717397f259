"""Rigid transforms and rotations (``transforms``): 4x4 homogeneous ``T_<to>_<from>`` in mm,
rotations in radians; the algebra behind every frame change of the paper (§II-A, §II-B.3, §II-C).
"""

from .transforms import (
    as_points,
    check_rigid,
    check_rotation,
    fit_sphere,
    invert_transform,
    make_transform,
    matrix_from_euler,
    matrix_from_rotvec,
    rotation_about_axis,
    rotation_angle,
    rotvec_from_matrix,
    transform_from_params,
    transform_points,
)

__all__ = [
    "make_transform",
    "invert_transform",
    "transform_points",
    "as_points",
    "check_rigid",
    "check_rotation",
    "rotation_about_axis",
    "rotation_angle",
    "matrix_from_euler",
    "matrix_from_rotvec",
    "rotvec_from_matrix",
    "transform_from_params",
    "fit_sphere",
]
