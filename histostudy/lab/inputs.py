"""The lab's inputs judged plausible before any work is done on them: the units of the flange poses
a robot reported at the calibration stations (:func:`check_flange_pose_units`).
"""

from __future__ import annotations

import math
import os

import numpy as np

__all__ = ["FLANGE_DISTANCE_MM", "FLANGE_UNIT_SPLIT", "check_flange_pose_units"]

#: The nearest and farthest a UR5e's flange gets from its base origin, in mm: the extremes of its
#: forward kinematics (histostudy.robot.UR5E's DH parameters) over all joint angles, self-collision
#: ignored. The 850 mm reach counts from the shoulder, 162.5 mm above the base, hence the far end.
FLANGE_DISTANCE_MM = (33.7, 1129.7)

#: The translation norm that tells the units apart. Any number between 1.13 (the farthest flange,
#: in metres) and 33.7 (the nearest, in millimetres) does for a UR5e; 6 is their geometric mean, so
#: either bound would have to be off by a factor of 5 before a plausible pose were refused.
FLANGE_UNIT_SPLIT = 6.0

# A UR pose's axis-angle turns by at most half a turn (pi) as the robot reports it; an equivalent
# reading turns by up to a full turn (2 pi); more than that is no rotation vector in radians.
_FULL_TURN_RAD = 2.0 * math.pi


def check_flange_pose_units(data: dict, path: str | os.PathLike) -> None:
    """Refuse flange poses in the wrong unit, with the unit they look like and the fix.

    A hand-eye calibration on flange poses in the wrong unit fails only at its end, with residuals of
    metres that read as bad pose estimates. The unit shows in the poses themselves: a UR5e's flange
    lies within :data:`FLANGE_DISTANCE_MM` of its base origin, and a UR pose's axis-angle never turns
    more than half a turn. Poses a UR5e can take in the stated units are never refused: a translation
    of norm below :data:`FLANGE_UNIT_SPLIT` given as mm, or above it given as m, or a rotation vector
    of norm above 2 pi, is.

    Args:
        data: the flange poses file's JSON (:func:`~histostudy.lab.load_flange_poses`, whose entries
            have been checked for shape and finiteness already): ``T_base_flange`` (4x4, mm), read
            when present, else ``ur_pose`` (``[x, y, z]`` m, ``[rx, ry, rz]`` axis-angle rad).
        path: the file, named in the message.

    Returns:
        None.

    Raises:
        ValueError: naming the file, the key, the stations and the unit the values look like.
    """
    source = f"flange poses file {str(path)!r}"
    if "T_base_flange" in data:
        poses = [np.asarray(T, dtype=np.float64) for T in data["T_base_flange"]]
        problems = _millimetre_problems([T[:3, 3] for T in poses])
    else:
        poses = [np.asarray(p, dtype=np.float64).reshape(-1) for p in data["ur_pose"]]
        problems = _metre_problems([p[:3] for p in poses]) + _radian_problems([p[3:] for p in poses])
    if problems:
        raise ValueError(f"{source}: " + "; ".join(problems))


def _stations(key: str, indices) -> str:
    return f"{key}[{', '.join(str(i) for i in indices)}]"


def _millimetre_problems(translations: list) -> list[str]:
    norms = np.array([np.linalg.norm(t) for t in translations])
    small = np.flatnonzero(norms < FLANGE_UNIT_SPLIT)
    if len(small) == 0:
        return []
    near, far = FLANGE_DISTANCE_MM
    if len(small) == len(norms):
        return [f"the T_base_flange translations are all under {FLANGE_UNIT_SPLIT:g} in norm (largest "
                f"{norms.max():.4g}), where millimetres are expected: they look like metres (a UR5e's flange lies "
                f"{near:g} to {far:g} mm from its base); multiply them by 1000, or give the poses as ur_pose "
                "([x, y, z] in m, [rx, ry, rz] in rad)"]
    return [f"{_stations('T_base_flange', small)}: translations of norm {np.round(norms[small], 4).tolist()}, "
            f"where millimetres are expected, put the flange nearer its base than a UR5e's gets ({near:g} mm): "
            "they look like metres; multiply them by 1000"]


def _metre_problems(translations: list) -> list[str]:
    norms = np.array([np.linalg.norm(t) for t in translations])
    large = np.flatnonzero(norms > FLANGE_UNIT_SPLIT)
    if len(large) == 0:
        return []
    near, far = (d / 1000.0 for d in FLANGE_DISTANCE_MM)
    if len(large) == len(norms):
        return [f"the ur_pose translations [x, y, z] are all over {FLANGE_UNIT_SPLIT:g} in norm (smallest "
                f"{norms.min():.4g}), where metres are expected: they look like millimetres (a UR5e's flange lies "
                f"{near:.3g} to {far:.3g} m from its base); divide x, y, z by 1000, or give the poses as "
                "T_base_flange (4x4, mm)"]
    return [f"{_stations('ur_pose', large)}: translations [x, y, z] of norm {np.round(norms[large], 4).tolist()}, "
            f"where metres are expected, lie beyond a UR5e's reach ({far:.3g} m from its base at most): they look "
            "like millimetres; divide x, y, z by 1000"]


def _radian_problems(rotation_vectors: list) -> list[str]:
    norms = np.array([np.linalg.norm(r) for r in rotation_vectors])
    beyond = np.flatnonzero(norms > _FULL_TURN_RAD)
    if len(beyond) == 0:
        return []
    return [f"{_stations('ur_pose', beyond)}: rotation vectors [rx, ry, rz] of norm "
            f"{np.round(norms[beyond], 4).tolist()}, more than a full turn (2 pi = {_FULL_TURN_RAD:.4f} rad) where "
            "an axis-angle in radians is expected (a UR reports at most pi): they look like degrees; multiply "
            "rx, ry, rz by pi/180"]
