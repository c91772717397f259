"""The calibrated chain run forwards to a target (§II-D, Fig. 2 step 3: :func:`tcp_for_target`,
:func:`target_orientation`), and the calibration that resolves the transducer's half-turn symmetry
(§II-C: :func:`calibrate_half_turns`). Transforms are 4x4 ``T_<to>_<from>`` in mm, the target in
the CBCT's C-arm frame (LPS, mm).
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
    """The treatment's transducer orientation (§II-D): propagation straight down (world +y, LPS).

    The axial rotation is the transducer's when the flange points straight down, turned by the
    smallest rotation that makes the beam point down.

    Args:
        calibration: the :class:`~.procedure.HandEyeCalibration` of the set-up.

    Returns:
        ``R_carm_transducer``, 3x3.

    Raises:
        TypeError: ``calibration`` is not a ``HandEyeCalibration``.
    """
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    R0 = calibration.T_carm_base[:3, :3] @ R_BASE_FLANGE_DOWN @ calibration.T_flange_transducer[:3, :3]
    z0, z1 = R0[:, 2], -DOWN
    axis = np.cross(z0, z1)
    s, c = np.linalg.norm(axis), float(z0 @ z1)
    turn = np.eye(3) if s < 1e-12 else matrix_from_rotvec(axis / s * np.arctan2(s, c))
    return turn @ R0


def tcp_for_target(calibration: HandEyeCalibration, target_mm, R_carm_transducer, T_flange_tcp=None) -> np.ndarray:
    """The flange's TCP pose that puts the TCP on a target (§II-D, Fig. 2 step 3).

    Args:
        calibration: the :class:`~.procedure.HandEyeCalibration` (``T_carm_base``,
            ``T_flange_transducer``).
        target_mm: the target in the C-arm (CBCT) frame, mm (LPS).
        R_carm_transducer: the transducer orientation at the target, 3x3 (e.g.
            :func:`target_orientation`).
        T_flange_tcp: the TCP in the flange frame, 4x4 mm; None: the estimated focal point,
            ``T_flange_transducer`` (a bias-corrected point otherwise).

    Returns:
        ``T_base_tcp``, 4x4 mm, the pose to command.
    """
    X = calibration.T_flange_transducer
    T_ft = X if T_flange_tcp is None else np.asarray(T_flange_tcp, float)
    # The TCP's place in the transducer frame (the focal point, or the bias-corrected point).
    local = (invert_transform(X) @ T_ft)[:3, 3]
    R = np.asarray(R_carm_transducer, float)
    T_carm_transducer = make_transform(R, np.asarray(target_mm, float) - R @ local)
    return calibration.T_base_carm @ T_carm_transducer @ invert_transform(X) @ T_ft


def calibrate_half_turns(T_base_flange_list, T_carm_transducer_list, *, nominal_T_flange_transducer=None,
                         **options) -> HandEyeCalibration:
    """:func:`~.procedure.calibrate` for a transducer that looks the same after a half turn (§II-C).

    Each pose estimate is read as itself or its half turn (:data:`HALF_TURN`); the combination
    whose calibration has the smallest largest rotation residual wins (the first pose fixes the
    reading of the others), then the global half turn that keeps ``T_flange_transducer`` closest to
    ``nominal_T_flange_transducer``. A half turn about the axis through the focal point leaves the
    focal point, and so the targeting, unchanged. 2**(n-1) calibrations for n poses.

    Args:
        T_base_flange_list: per pose, 4x4 ``T_base_flange`` in mm.
        T_carm_transducer_list: per pose, 4x4 ``T_carm_transducer`` in mm (either half-turn reading).
        nominal_T_flange_transducer: the mount as designed, 4x4 mm; None keeps the first pose's
            reading.
        **options: passed to :func:`~.procedure.calibrate`.

    Returns:
        The :class:`~.procedure.HandEyeCalibration` of the readings chosen.

    Raises:
        TypeError, ValueError: bad pose lists (as :func:`~.procedure.calibrate`).
        DegenerateMotionError: every reading's poses are degenerate.
    """
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

    def angle(c: HandEyeCalibration) -> float:
        return rotation_angle(c.T_flange_transducer[:3, :3].T @ nominal[:3, :3])

    return flipped if angle(flipped) < angle(cal) else cal
