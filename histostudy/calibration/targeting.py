"""The calibrated chain run forwards to a target (§II-D, Fig. 2 step 3), and the half-turn symmetry of
the transducer that the calibration must resolve (§II-C).

With a :class:`~.procedure.HandEyeCalibration`, :func:`tcp_for_target` gives the ``T_base_tcp``
that puts the TCP (the estimated focal point, or a bias-corrected point) on a target picked in the
CBCT (C-arm frame, LPS, mm) with a chosen transducer orientation; :func:`target_orientation` is the
treatment's orientation, propagation straight down. :func:`calibrate_half_turns` is
:func:`~.procedure.calibrate` for a transducer that looks the same after a half turn about its
axis (the paper's: elliptical aperture, four quadrants, central cutout), so that a pose estimate
may return either of two poses: it picks, pose by pose, the reading that fits one rigid chain.
Transforms are 4x4 ``T_<to>_<from>`` in mm (docs/architecture.md, "Frames and units").
"""

from __future__ import annotations

import itertools

import numpy as np

from histostudy.geometry import invert_transform, make_transform, matrix_from_rotvec, rotation_angle

from .axxb import DegenerateMotionError, check_transform_list
from .procedure import HandEyeCalibration, calibrate
from .sensitivity import R_BASE_FLANGE_DOWN

__all__ = ["DOWN", "HALF_TURN", "calibrate_half_turns", "target_orientation", "tcp_for_target"]

#: World direction of propagation with the transducer pointing down (LPS: +y is posterior).
DOWN = np.array([0.0, 1.0, 0.0])

#: A half turn about the transducer's z axis: the aperture, gaps and cutout look the same after it.
HALF_TURN = np.diag([-1.0, -1.0, 1.0, 1.0])


def target_orientation(calibration: HandEyeCalibration) -> np.ndarray:
    """``R_carm_transducer`` of the treatment: propagation straight down (world +y), the axial
    rotation the transducer has when the flange points straight down (the smallest turn from it)."""
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    R0 = calibration.T_carm_base[:3, :3] @ R_BASE_FLANGE_DOWN @ calibration.T_flange_transducer[:3, :3]
    z0, z1 = R0[:, 2], -DOWN
    axis = np.cross(z0, z1)
    s, c = np.linalg.norm(axis), float(z0 @ z1)
    turn = np.eye(3) if s < 1e-12 else matrix_from_rotvec(axis / s * np.arctan2(s, c))
    return turn @ R0


def tcp_for_target(calibration: HandEyeCalibration, target_mm, R_carm_transducer, T_flange_tcp=None) -> np.ndarray:
    """``T_base_tcp`` that puts the TCP (``T_flange_tcp``; default the estimated focal point
    ``T_flange_transducer``) on ``target_mm`` (C-arm frame) with the transducer orientation
    ``R_carm_transducer``."""
    X = calibration.T_flange_transducer
    T_ft = X if T_flange_tcp is None else np.asarray(T_flange_tcp, float)
    # The TCP's place in the transducer frame (the focal point, or the bias-corrected point).
    local = (invert_transform(X) @ T_ft)[:3, 3]
    R = np.asarray(R_carm_transducer, float)
    T_carm_transducer = make_transform(R, np.asarray(target_mm, float) - R @ local)
    return calibration.T_base_carm @ T_carm_transducer @ invert_transform(X) @ T_ft


def calibrate_half_turns(T_base_flange_list, T_carm_transducer_list, *, nominal_T_flange_transducer=None,
                         **options) -> HandEyeCalibration:
    """:func:`~.procedure.calibrate` with each pose estimate read as itself or its half turn
    (:data:`HALF_TURN`): the combination whose calibration has the smallest largest rotation
    residual wins (the first pose fixes the reading of the others), then the global half turn that
    keeps ``T_flange_transducer`` closest to ``nominal_T_flange_transducer`` (the mount as designed;
    None keeps the first pose's reading). A half turn about the axis through the focal point leaves
    the focal point, and so the targeting, unchanged. ``options`` go to ``calibrate``.
    2**(n-1) calibrations for n poses (8 for the paper's 4)."""
    F = check_transform_list(T_base_flange_list, "T_base_flange_list", 3)
    C = check_transform_list(T_carm_transducer_list, "T_carm_transducer_list", 3)
    best = None
    for flips in itertools.product((False, True), repeat=len(C) - 1):
        Cs = [C[0]] + [c @ HALF_TURN if f else c for c, f in zip(C[1:], flips)]
        try:
            cal = calibrate(F, Cs, **options)
        except DegenerateMotionError:
            continue
        if best is None or cal.max_rotation_residual_deg < best[0]:
            best = (cal.max_rotation_residual_deg, Cs, cal)
    if best is None:
        # Every reading degenerate: calibrate the estimates as given, for its error message.
        return calibrate(F, C, **options)
    _, Cs, cal = best
    if nominal_T_flange_transducer is None:
        return cal
    nominal = check_transform_list([nominal_T_flange_transducer], "nominal_T_flange_transducer", 1)[0]
    flipped = calibrate(F, [c @ HALF_TURN for c in Cs], **options)
    angle = lambda c: rotation_angle(c.T_flange_transducer[:3, :3].T @ nominal[:3, :3])
    return flipped if angle(flipped) < angle(cal) else cal
