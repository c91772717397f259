"""The robot to C-arm calibration of §II-C (eq. 5-7): flange and transducer poses in,
``T_flange_transducer`` and ``T_carm_base`` out (:class:`HandEyeCalibration`), with the residuals
that gate targeting and the flange pose that puts the focal point on a target. Lengths in mm,
residual angles in degrees; the chain and its A and B are derived in docs/pose-estimation.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from histostudy.core import atomic_write_json, stage, to_jsonable
from histostudy.geometry import check_rigid, check_rotation, invert_transform, make_transform

from .axxb import (
    MIN_AXIS_ANGLE_DEG,
    MIN_ROTATION_DEG,
    DegenerateMotionError,
    check_transform_list,
    solution_details,
    solve_motion_dual_quaternions,
)
from .dual_quaternion import dual_quaternions_from_transforms, invert_transforms, rotation_angles_rad

__all__ = ["CalibrationError", "HandEyeCalibration", "calibrate", "flange_pose_for_target", "motion_pairs"]

#: The schema tag a saved calibration carries, named after the package that writes it.
SCHEMA = "histostudy.calibration/1"
#: Tags of files written by earlier versions that still load (the same fields; 0.1.0 named the module).
LEGACY_SCHEMAS = ("histostudy.handeye/1",)


class CalibrationError(RuntimeError):
    """A calibration whose residuals exceed the stated bound; targeting must not use it."""


def motion_pairs(n_poses: int, pairs: str = "all") -> list[tuple[int, int]]:
    """Pose index pairs (i, j), i < j, that make the motions: ``"all"`` n(n-1)/2 pairs (OpenCV's
    choice), ``"consecutive"`` (i, i+1) — the paper's n-1 motions for n poses."""
    if pairs == "all":
        return [(i, j) for i in range(n_poses) for j in range(i + 1, n_poses)]
    if pairs == "consecutive":
        return [(i, i + 1) for i in range(n_poses - 1)]
    raise ValueError(f"pairs must be 'all' or 'consecutive', got {pairs!r}")


def _mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of (n, 3, 3) rotations: the rotation nearest (Frobenius) to their mean."""
    U, _, Vt = np.linalg.svd(np.mean(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


@dataclass
class HandEyeCalibration:
    """The result of :func:`calibrate` (§II-C): the transducer on the flange and the robot base in the C-arm.

    Per pose i the chain's prediction ``P_i = T_carm_base @ T_base_flange_i @ T_flange_transducer``
    is compared with the pose estimate ``C_i = T_carm_transducer_i`` (eq. 5).

    Args:
        T_flange_transducer: 4x4 rigid, mm: the transducer in the flange frame (X; the paper's
            ``eTh`` read as a point map).
        T_carm_base: 4x4 rigid, mm: the robot base in the C-arm frame (Y; the paper's ``rTc``).
        rotation_residuals_deg: per pose, the angle of ``R(P_i)^T R(C_i)`` in degrees.
        translation_residuals_mm: per pose, the distance between the transducer origins in mm.
        focal_residuals_mm: per pose, the distance between the focal points ``P_i @ f`` and
            ``C_i @ f`` in mm, ``f = focal_point_transducer_mm``.
        motion_rotation_residuals_deg: per motion, the AX = XB rotation residual in degrees.
        motion_translation_residuals_mm: per motion, the AX = XB translation residual in mm.
        focal_point_transducer_mm: the focal point in the transducer frame, mm (the origin by the
            convention of docs/architecture.md, where the two residuals coincide).
        pairs: the motion pairs used (:func:`motion_pairs`): ``"all"`` or ``"consecutive"``.
        method: the AX = XB solver, ``"daniilidis"``.

    Raises:
        ValueError: a transform is not rigid, the per-pose residuals differ in length, or
            ``focal_point_transducer_mm`` is not 3 finite numbers.
    """

    T_flange_transducer: np.ndarray
    T_carm_base: np.ndarray
    rotation_residuals_deg: np.ndarray
    translation_residuals_mm: np.ndarray
    focal_residuals_mm: np.ndarray
    motion_rotation_residuals_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    motion_translation_residuals_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    focal_point_transducer_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pairs: str = "all"
    method: str = "daniilidis"

    def __post_init__(self):
        self.T_flange_transducer = check_rigid(self.T_flange_transducer, "T_flange_transducer").copy()
        self.T_carm_base = check_rigid(self.T_carm_base, "T_carm_base").copy()
        for name in (
            "rotation_residuals_deg",
            "translation_residuals_mm",
            "focal_residuals_mm",
            "motion_rotation_residuals_deg",
            "motion_translation_residuals_mm",
        ):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.float64).reshape(-1))
        n = len(self.rotation_residuals_deg)
        if len(self.translation_residuals_mm) != n or len(self.focal_residuals_mm) != n:
            raise ValueError(
                f"per-pose residuals must have one value per pose, got lengths {n}, "
                f"{len(self.translation_residuals_mm)}, {len(self.focal_residuals_mm)}"
            )
        f = np.asarray(self.focal_point_transducer_mm, dtype=np.float64).reshape(-1)
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise ValueError(
                f"focal_point_transducer_mm must be 3 finite numbers, got {self.focal_point_transducer_mm!r}")
        self.focal_point_transducer_mm = f

    # ---- summaries
    @property
    def n_poses(self) -> int:
        return len(self.rotation_residuals_deg)

    @property
    def T_base_carm(self) -> np.ndarray:
        return invert_transform(self.T_carm_base)

    @property
    def rms_rotation_residual_deg(self) -> float:
        return float(np.sqrt(np.mean(self.rotation_residuals_deg**2)))

    @property
    def max_rotation_residual_deg(self) -> float:
        return float(np.max(self.rotation_residuals_deg))

    @property
    def rms_translation_residual_mm(self) -> float:
        return float(np.sqrt(np.mean(self.translation_residuals_mm**2)))

    @property
    def max_translation_residual_mm(self) -> float:
        return float(np.max(self.translation_residuals_mm))

    @property
    def rms_focal_residual_mm(self) -> float:
        return float(np.sqrt(np.mean(self.focal_residuals_mm**2)))

    @property
    def max_focal_residual_mm(self) -> float:
        return float(np.max(self.focal_residuals_mm))

    def summary(self) -> dict:
        """The RMS/max residuals and n_poses as a flat dict (for tables)."""
        return {
            "n_poses": self.n_poses,
            "rms_rotation_residual_deg": self.rms_rotation_residual_deg,
            "max_rotation_residual_deg": self.max_rotation_residual_deg,
            "rms_translation_residual_mm": self.rms_translation_residual_mm,
            "max_translation_residual_mm": self.max_translation_residual_mm,
            "rms_focal_residual_mm": self.rms_focal_residual_mm,
            "max_focal_residual_mm": self.max_focal_residual_mm,
        }

    # ---- the gate targeting runs behind
    def check(self, max_focal_residual_mm: float = 2.0, max_rotation_residual_deg: float = 1.0) -> HandEyeCalibration:
        """The gate targeting runs behind: every pose's residuals within the bounds.

        The defaults (2 mm, 1°) are the study's bound: about the paper's targeting accuracy (1.6 mm
        mean), far above the residuals of a sound calibration.

        Args:
            max_focal_residual_mm: largest focal-point residual accepted, mm.
            max_rotation_residual_deg: largest rotation residual accepted, degrees.

        Returns:
            ``self``.

        Raises:
            ValueError: a bound is not a finite number > 0.
            CalibrationError: a pose's residual exceeds its bound (the message lists each).
        """
        for name, v in (("max_focal_residual_mm", max_focal_residual_mm),
                        ("max_rotation_residual_deg", max_rotation_residual_deg)):
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        problems = []
        for i, (f, r) in enumerate(zip(self.focal_residuals_mm, self.rotation_residuals_deg)):
            if f > max_focal_residual_mm:
                problems.append(f"pose {i}: focal-point residual {f:.3f} mm > {max_focal_residual_mm:g} mm")
            if r > max_rotation_residual_deg:
                problems.append(f"pose {i}: rotation residual {r:.3f} deg > {max_rotation_residual_deg:g} deg")
        if problems:
            raise CalibrationError(
                "hand-eye calibration residuals exceed the stated bound; targeting refuses to run on it "
                "(re-acquire the poses, check the pose estimates, or check that the flange poses are the "
                "robot's at these stations, in their order): " + "; ".join(problems)
            )
        return self

    def flange_pose_for_target(self, target_carm_mm, orientation) -> np.ndarray:
        """See :func:`flange_pose_for_target`."""
        return flange_pose_for_target(self, target_carm_mm, orientation)

    def predict_T_carm_transducer(self, T_base_flange) -> np.ndarray:
        """The transducer pose the chain predicts for a flange pose: ``T_carm_base @ F @ X``."""
        F = check_rigid(T_base_flange, "T_base_flange")
        return self.T_carm_base @ F @ self.T_flange_transducer

    # ---- persistence
    def to_dict(self) -> dict:
        """The calibration as plain JSON.

        Returns:
            A dict of lists of floats: ``schema``, ``units`` (mm, deg), ``method``, ``pairs``, the two
            transforms, the focal point and the residuals, and the :meth:`summary` for human readers.
        """
        return to_jsonable(
            {
                "schema": SCHEMA,
                "units": {"length": "mm", "angle": "deg"},
                "method": self.method,
                "pairs": self.pairs,
                "T_flange_transducer": self.T_flange_transducer,
                "T_carm_base": self.T_carm_base,
                "focal_point_transducer_mm": self.focal_point_transducer_mm,
                "rotation_residuals_deg": self.rotation_residuals_deg,
                "translation_residuals_mm": self.translation_residuals_mm,
                "focal_residuals_mm": self.focal_residuals_mm,
                "motion_rotation_residuals_deg": self.motion_rotation_residuals_deg,
                "motion_translation_residuals_mm": self.motion_translation_residuals_mm,
                "summary": self.summary(),
            }
        )

    @classmethod
    def from_dict(cls, d: dict) -> HandEyeCalibration:
        """The calibration of a :meth:`to_dict` dict.

        Args:
            d: the dict (its ``schema`` this one's or an earlier one).

        Returns:
            The :class:`HandEyeCalibration`.

        Raises:
            TypeError: ``d`` is not a dict.
            ValueError: ``d``'s schema is unknown, a key is missing, or a value is invalid.
        """
        if not isinstance(d, dict):
            raise TypeError(f"d must be a dict from HandEyeCalibration.to_dict, got {type(d).__name__}")
        if d.get("schema") not in (SCHEMA, *LEGACY_SCHEMAS):
            raise ValueError(f"d['schema'] must be {SCHEMA!r} (or an earlier {', '.join(map(repr, LEGACY_SCHEMAS))}), "
                             f"got {d.get('schema')!r}")
        missing = [k for k in ("T_flange_transducer", "T_carm_base", "rotation_residuals_deg",
                               "translation_residuals_mm", "focal_residuals_mm") if k not in d]
        if missing:
            raise ValueError(f"d is missing the keys {missing}")
        return cls(
            T_flange_transducer=np.array(d["T_flange_transducer"], dtype=np.float64),
            T_carm_base=np.array(d["T_carm_base"], dtype=np.float64),
            rotation_residuals_deg=d["rotation_residuals_deg"],
            translation_residuals_mm=d["translation_residuals_mm"],
            focal_residuals_mm=d["focal_residuals_mm"],
            motion_rotation_residuals_deg=d.get("motion_rotation_residuals_deg", []),
            motion_translation_residuals_mm=d.get("motion_translation_residuals_mm", []),
            focal_point_transducer_mm=d.get("focal_point_transducer_mm", [0.0, 0.0, 0.0]),
            pairs=d.get("pairs", "all"),
            method=d.get("method", "daniilidis"),
        )

    def save(self, path) -> Path:
        """Write :meth:`to_dict` as JSON atomically (the whole file or none).

        Args:
            path: the file to write.

        Returns:
            The path written.
        """
        return atomic_write_json(path, self.to_dict())

    @classmethod
    def load(cls, path) -> HandEyeCalibration:
        """The calibration saved by :meth:`save`.

        Args:
            path: the JSON file.

        Returns:
            The :class:`HandEyeCalibration`.

        Raises:
            FileNotFoundError: no file at ``path``.
            TypeError, ValueError: the file's content is not a calibration (:meth:`from_dict`).
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"path {str(path)!r}: no hand-eye calibration file there")
        return cls.from_dict(json.loads(path.read_text(encoding="utf-8")))


@stage("calibrate")
def calibrate(
    T_base_flange_list,
    T_carm_transducer_list,
    *,
    pairs: str = "all",
    focal_point_transducer_mm=(0.0, 0.0, 0.0),
    min_rotation_deg: float = MIN_ROTATION_DEG,
    min_axis_angle_deg: float = MIN_AXIS_ANGLE_DEG,
) -> HandEyeCalibration:
    """Calibrate the robot to the C-arm from n >= 3 poses (§II-C, eq. 5-8; the paper uses 4).

    Solves ``(F_j^-1 F_i) X = X (C_j^-1 C_i)`` (eq. 7) over the index ``pairs`` for
    ``X = T_flange_transducer`` by Daniilidis' dual quaternions (eq. 8), then ``T_carm_base`` as the
    chordal mean of the rotations of ``C_i X^-1 F_i^-1`` and the translation that fits the focal
    points in least squares given that rotation (docs/pose-estimation.md, "The chain and AX = XB").

    Args:
        T_base_flange_list: per pose, the flange pose from the encoders, 4x4 ``T_base_flange`` in mm
            (the paper's ``rTe``).
        T_carm_transducer_list: per pose, the pose estimate of the transducer at that flange pose,
            4x4 ``T_carm_transducer`` in mm (the paper's ``hTc``, eq. 5).
        pairs: which pose pairs make the motions: ``"all"`` (n(n-1)/2, OpenCV's choice) or
            ``"consecutive"`` (the paper's n-1).
        focal_point_transducer_mm: the focal point in the transducer frame, mm (3 numbers).
        min_rotation_deg: motions rotating less than this (degrees) carry no usable axis.
        min_axis_angle_deg: rotation axes closer than this (degrees) count as parallel.

    Returns:
        The :class:`HandEyeCalibration`, with its per-pose and per-motion residuals.

    Raises:
        TypeError: a pose list is not a list of transforms.
        ValueError: a list holds fewer than 3 transforms or a non-rigid one, the lists differ in
            length, ``pairs`` is unknown or ``focal_point_transducer_mm`` is not 3 finite numbers.
        DegenerateMotionError: the poses do not determine the calibration (too few motions rotate,
            or their rotation axes are all parallel).
    """
    F = check_transform_list(T_base_flange_list, "T_base_flange_list", 3)
    C = check_transform_list(T_carm_transducer_list, "T_carm_transducer_list", 3)
    if len(F) != len(C):
        raise ValueError(
            f"T_base_flange_list and T_carm_transducer_list must pair up pose by pose, "
            f"got {len(F)} and {len(C)} transforms"
        )
    f = np.asarray(focal_point_transducer_mm, dtype=np.float64).reshape(-1)
    if f.shape != (3,) or not np.all(np.isfinite(f)):
        raise ValueError(f"focal_point_transducer_mm must be 3 finite numbers (mm), got {focal_point_transducer_mm!r}")
    i, j = np.array(motion_pairs(len(F), pairs)).T
    A = invert_transforms(F[j]) @ F[i]
    B = invert_transforms(C[j]) @ C[i]
    try:
        X, sv, flipped = solve_motion_dual_quaternions(
            dual_quaternions_from_transforms(A), dual_quaternions_from_transforms(B), min_rotation_deg,
            min_axis_angle_deg,
        )
    except DegenerateMotionError as exc:
        raise DegenerateMotionError(
            f"T_base_flange_list / T_carm_transducer_list: the {len(F)} poses do not determine the calibration: {exc}"
        ) from exc
    sol = solution_details(A, B, X, sv, flipped)
    # Y = C_i X^-1 F_i^-1 for every pose: rotation by the chordal mean, then the translation that
    # fits the focal points best (least squares) given that rotation - the point targeting needs.
    FX = F @ X
    R_Y = _mean_rotation(C[:, :3, :3] @ np.swapaxes(FX[:, :3, :3], 1, 2))
    focal_carm = C[:, :3, :3] @ f + C[:, :3, 3]
    focal_base = FX[:, :3, :3] @ f + FX[:, :3, 3]
    t_Y = np.mean(focal_carm - focal_base @ R_Y.T, axis=0)
    Y = make_transform(R_Y, t_Y)
    P = Y @ FX  # the chain's prediction of every pose estimate
    rot = np.degrees(rotation_angles_rad(np.swapaxes(P[:, :3, :3], 1, 2) @ C[:, :3, :3]))
    trans = np.linalg.norm(P[:, :3, 3] - C[:, :3, 3], axis=1)
    focal = np.linalg.norm((P[:, :3, :3] - C[:, :3, :3]) @ f + P[:, :3, 3] - C[:, :3, 3], axis=1)
    return HandEyeCalibration(
        T_flange_transducer=X,
        T_carm_base=Y,
        rotation_residuals_deg=rot,
        translation_residuals_mm=trans,
        focal_residuals_mm=focal,
        motion_rotation_residuals_deg=sol.rotation_residuals_deg,
        motion_translation_residuals_mm=sol.translation_residuals_mm,
        focal_point_transducer_mm=f,
        pairs=pairs,
    )


def flange_pose_for_target(calibration: HandEyeCalibration, target_carm_mm, orientation) -> np.ndarray:
    """``T_base_flange`` that puts the focal point on ``target_carm_mm`` (C-arm frame, mm).

    ``orientation``: the transducer orientation to keep, a 3x3 ``R_carm_transducer`` or a 4x4
    ``T_carm_transducer`` (e.g. the current pose; only its rotation is used). The desired pose
    ``T_carm_transducer_desired`` has that rotation and places ``focal_point_transducer_mm`` on the
    target; then ``T_base_flange = inv(T_carm_base) @ T_carm_transducer_desired @
    inv(T_flange_transducer)`` (the chain of eq. 6 solved for the flange).
    """
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    target = np.asarray(target_carm_mm, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target_carm_mm must be 3 finite numbers (C-arm frame, mm), got {target_carm_mm!r}")
    o = np.asarray(orientation, dtype=np.float64)
    if o.shape == (4, 4):
        R = check_rigid(o, "orientation")[:3, :3]
    elif o.shape == (3, 3):
        R = check_rotation(o, "orientation")
    else:
        raise ValueError(
            f"orientation must be a 3x3 rotation R_carm_transducer or a 4x4 T_carm_transducer, got shape {o.shape}"
        )
    T_des = make_transform(R, target - R @ calibration.focal_point_transducer_mm)
    return invert_transform(calibration.T_carm_base) @ T_des @ invert_transform(calibration.T_flange_transducer)

