"""Simulated calibrations (§II-C; the sensitivity study is beyond the paper): flange poses and the
transducer poses they give, pose-estimation noise, and the Monte-Carlo of the calibration error
against the number of poses and the noise (a sweep of :func:`histostudy.core.run_sweep`). Lengths
in mm, angles in degrees where the names say so.
"""

from __future__ import annotations

import numpy as np

from histostudy.core import SweepExecutor, as_generator, run_sweep
from histostudy.geometry import check_rigid, invert_transform, make_transform, matrix_from_rotvec

from .dual_quaternion import rotation_angles_rad
from .procedure import calibrate

__all__ = ["R_BASE_FLANGE_DOWN", "calibration_sensitivity", "perturb_pose", "simulate_poses"]

#: Nominal set-up of the sensitivity study (mm): transducer focal point 250 mm below the flange
#: along the tool axis; flange poses around a point 600 mm out from the base and 550 mm up; the
#: cart placed so that the nominal focal point falls on the isocentre (calibrate where you treat).
NOMINAL_FLANGE_TO_FOCAL_MM = 250.0
NOMINAL_FLANGE_IN_BASE_MM = (600.0, 0.0, 550.0)
#: Nominal downward flange orientation in the base frame (180° about x: tool z points to base -z).
R_BASE_FLANGE_DOWN = np.diag([1.0, -1.0, -1.0])


def simulate_poses(
    n_poses: int,
    T_flange_transducer,
    T_carm_base,
    rng,
    *,
    box_mm: float = 300.0,
    max_tilt_deg: float = 30.0,
    flange_centre_base_mm=NOMINAL_FLANGE_IN_BASE_MM,
):
    """Random reachable-looking flange poses and the transducer poses they give (noise-free).

    Flange origins uniform in a ``box_mm`` cube centred on ``flange_centre_base_mm`` (base frame);
    orientations a rotation vector uniform in the ball of radius ``max_tilt_deg`` about the nominal
    downward orientation (flange z pointing to base -z). Returns ``(T_base_flange list,
    T_carm_transducer list)``.
    """
    rng = as_generator(rng)
    if int(n_poses) != n_poses or n_poses < 1:
        raise ValueError(f"n_poses must be a positive integer, got {n_poses!r}")
    for name, v in (("box_mm", box_mm), ("max_tilt_deg", max_tilt_deg)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    X = check_rigid(T_flange_transducer, "T_flange_transducer")
    Y = check_rigid(T_carm_base, "T_carm_base")
    R_down = R_BASE_FLANGE_DOWN
    centre = np.asarray(flange_centre_base_mm, dtype=np.float64).reshape(3)
    F, C = [], []
    for _ in range(int(n_poses)):
        tilt = _ball(rng, np.radians(max_tilt_deg))
        Fi = make_transform(R_down @ matrix_from_rotvec(tilt), centre + rng.uniform(-box_mm / 2, box_mm / 2, 3))
        F.append(Fi)
        C.append(Y @ Fi @ X)
    return F, C


def perturb_pose(T, translation_sd_mm: float, rotation_sd_deg: float, rng) -> np.ndarray:
    """``T @ dT``: noise in the pose's own frame, about its origin (the focal point for a transducer pose).

    Args:
        T: a 4x4 rigid pose (mm), e.g. ``T_carm_transducer``.
        translation_sd_mm: per-axis Gaussian translation noise, sd in mm.
        rotation_sd_deg: per-axis Gaussian rotation-vector noise, sd in degrees.
        rng: an int seed or a numpy Generator.

    Returns:
        The perturbed 4x4 pose.

    Raises:
        ValueError: an sd is negative or not finite, or ``T`` is not rigid.
    """
    rng = as_generator(rng)
    for name, v in (("translation_sd_mm", translation_sd_mm), ("rotation_sd_deg", rotation_sd_deg)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    dT = make_transform(
        matrix_from_rotvec(rng.normal(0.0, np.radians(rotation_sd_deg), 3)), rng.normal(0.0, translation_sd_mm, 3)
    )
    return check_rigid(T, "T") @ dT


def calibration_sensitivity(
    n_poses_list=(4, 8, 12),
    noise_levels=((0.5, 0.2),),
    n_trials: int = 20,
    rng=0,
    *,
    target_carm_mm=(0.0, 0.0, 0.0),
    pairs: str = "all",
    box_mm: float = 300.0,
    max_tilt_deg: float = 30.0,
    executor: SweepExecutor | str | None = None,
):
    """Monte-Carlo calibration errors against the number of poses and the pose noise (§II-C; beyond the paper).

    Per trial: a random true mounting ``T_flange_transducer`` (focal point 250 mm down the tool
    axis ± 20 mm per axis, tilted up to 10°) and cart position ``T_carm_base`` (yaw uniform ±180°,
    tilt up to 2°, the nominal focal point within ±50 mm per axis of the isocentre); ``n_poses``
    flange poses from :func:`simulate_poses`; the pose estimates perturbed by :func:`perturb_pose`;
    :func:`~.procedure.calibrate`. One trial's poses and truth are reused across its noise levels
    (a paired comparison). All draws come from ``rng`` in this process; the calibrations then run on
    ``executor``, so the rows are the same bit for bit whatever runs them.

    Args:
        n_poses_list: the pose counts to try, each >= 3.
        noise_levels: ``(translation sd mm, rotation sd deg)`` pairs, per axis, each >= 0.
        n_trials: trials per pose count, >= 1.
        rng: an int seed or a numpy Generator.
        target_carm_mm: the target in the C-arm frame, mm (default the isocentre).
        pairs: the motion pairs of :func:`~.procedure.calibrate`.
        box_mm: edge of the cube of flange origins, mm.
        max_tilt_deg: largest flange tilt from straight down, degrees.
        executor: where the calibrations run (:func:`histostudy.core.run_sweep`: ``"sequential"``,
            ``"local"``, ``"local:<workers>"``, ``"tcp://host:port"``, a
            :class:`~histostudy.core.SweepExecutor`, or None: ``$HISTOSTUDY_SCHEDULER``, else
            sequential).

    Returns:
        A DataFrame, one row per (n_poses, noise, trial): ``X_rotation_error_deg``,
        ``X_translation_error_mm`` (of ``T_flange_transducer``), ``Y_rotation_error_deg``,
        ``Y_translation_error_mm`` (of ``T_carm_base``), ``target_error_mm`` (the true focal point's
        distance from the target after moving the flange to the estimate's pose for it) and
        ``rms_focal_residual_mm`` (what :meth:`HandEyeCalibration.check` sees).

    Raises:
        ValueError: a pose count < 3, a noise level that is not a pair of finite numbers >= 0, or
            ``n_trials`` < 1.
    """
    import pandas as pd

    rng = as_generator(rng)
    n_list = [int(n) for n in n_poses_list]
    if not n_list or min(n_list) < 3:
        raise ValueError(f"n_poses_list must hold pose counts >= 3, got {list(n_poses_list)!r}")
    levels = [tuple(float(x) for x in lv) for lv in noise_levels]
    if not levels or any(len(lv) != 2 or min(lv) < 0 or not np.all(np.isfinite(lv)) for lv in levels):
        raise ValueError(f"noise_levels must be (translation sd mm, rotation sd deg) pairs >= 0, got {noise_levels!r}")
    if int(n_trials) < 1:
        raise ValueError(f"n_trials must be >= 1, got {n_trials!r}")
    target = np.asarray(target_carm_mm, dtype=np.float64).reshape(3)
    # every random draw here, in the order of the single-stream loop, so that the numbers do not
    # depend on the executor; the trials (calibrate and score) then run anywhere
    trials = [(n, trial, *_draw_trial(n, levels, rng, box_mm, max_tilt_deg))
              for n in n_list for trial in range(int(n_trials))]
    per_trial = run_sweep(_score_trial, trials, executor=executor, shared=dict(target=target, pairs=pairs))
    return pd.DataFrame([row for rows in per_trial for row in rows])


def _draw_trial(n: int, levels, rng: np.random.Generator, box_mm: float, max_tilt_deg: float):
    """One trial's truth (``X_true``, ``Y_true``), flange poses and noisy transducer poses per noise level."""
    X_true = make_transform(
        matrix_from_rotvec(_ball(rng, np.radians(10.0))),
        [0.0, 0.0, NOMINAL_FLANGE_TO_FOCAL_MM] + rng.uniform(-20.0, 20.0, 3),
    )
    yaw = matrix_from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    R_Y = matrix_from_rotvec(_ball(rng, np.radians(2.0))) @ yaw
    focal_nominal_base = np.asarray(NOMINAL_FLANGE_IN_BASE_MM) + R_BASE_FLANGE_DOWN @ X_true[:3, 3]
    Y_true = make_transform(R_Y, -R_Y @ focal_nominal_base + rng.uniform(-50.0, 50.0, 3))
    F, C_true = simulate_poses(n, X_true, Y_true, rng, box_mm=box_mm, max_tilt_deg=max_tilt_deg)
    noisy = [(t_sd, r_sd, [perturb_pose(Ci, t_sd, r_sd, rng) for Ci in C_true]) for t_sd, r_sd in levels]
    return X_true, Y_true, F, noisy


def _score_trial(trial, *, target: np.ndarray, pairs: str) -> list[dict]:
    """The rows of one drawn trial: calibrate at each noise level and measure the errors (a sweep task)."""
    n, index, X_true, Y_true, F, noisy = trial
    R_nominal = Y_true[:3, :3] @ R_BASE_FLANGE_DOWN @ X_true[:3, :3]
    rows = []
    for t_sd, r_sd, C in noisy:
        cal = calibrate(F, C, pairs=pairs)
        F_target = cal.flange_pose_for_target(target, R_nominal)
        focal_true = (Y_true @ F_target @ X_true)[:3, 3]
        E_X = invert_transform(X_true) @ cal.T_flange_transducer
        E_Y = invert_transform(Y_true) @ cal.T_carm_base
        rows.append(
            {
                "n_poses": n,
                "noise_translation_mm": t_sd,
                "noise_rotation_deg": r_sd,
                "trial": index,
                "X_rotation_error_deg": np.degrees(rotation_angles_rad(E_X[:3, :3])),
                "X_translation_error_mm": float(np.linalg.norm(cal.T_flange_transducer[:3, 3] - X_true[:3, 3])),
                "Y_rotation_error_deg": np.degrees(rotation_angles_rad(E_Y[:3, :3])),
                "Y_translation_error_mm": float(np.linalg.norm(cal.T_carm_base[:3, 3] - Y_true[:3, 3])),
                "target_error_mm": float(np.linalg.norm(focal_true - target)),
                "rms_focal_residual_mm": cal.rms_focal_residual_mm,
            }
        )
    return rows


def _ball(rng: np.random.Generator, radius: float) -> np.ndarray:
    """A vector uniform in the 3-ball of ``radius``."""
    d = rng.normal(size=3)
    return d / np.linalg.norm(d) * radius * rng.uniform() ** (1 / 3)
