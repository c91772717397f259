"""A biplane cine of the transducer carried by the robot between the study's margin points (§II-D), as
single-frame DICOM XA objects timed by their acquisition times, the truth beside them (beyond the
paper). The tour, its minimum-jerk profile and the files: docs/study-sections.md, "06".
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from histostudy.core import atomic_write_json, check_positive, to_jsonable
from histostudy.geometry import invert_transform
from histostudy.imaging import View, default_biplane, detector_counts, save_views, write_xa
from histostudy.robot import forward_kinematics

from ..pose.geometry import margin_positions
from ..targeting.setup import TargetingStudyConfig, draw_ground_truth, start_joints
from .lab_dataset import LabScene

__all__ = ["MARGIN_TOUR", "MovingCine", "RobotPath", "load_moving_cine", "robot_path", "write_moving_cine"]

CINE_FORMAT = "histostudy.moving_cine/1"

#: The order the robot visits the zone's centre and its margin points (§II-D), repeated.
MARGIN_TOUR = ("centre", "left", "right", "centre", "top", "bottom", "centre", "front", "back")

#: When the first frame is taken (the frames' AcquisitionDateTime starts here).
T0 = _dt.datetime(2023, 1, 19, 11, 0, 0)


@dataclass(frozen=True)
class RobotPath:
    """The focal point's tour (C-arm frame, mm) with its timing (:func:`robot_path`).

    Args:
        T_centre: the pose at the zone's centre, 4x4 ``T_carm_transducer`` (mm), whose orientation
            the robot holds.
        names: the waypoints' names (``MARGIN_TOUR`` entries).
        waypoints_mm: the waypoints, ``(m, 3)`` mm.
        leg_start_s: per leg ``k`` (waypoint k to k + 1), its start, s.
        leg_s: per leg, its duration, s.
        dwell_s: how long each waypoint is held before its leg starts, s.
    """

    T_centre: np.ndarray
    names: tuple
    waypoints_mm: np.ndarray
    leg_start_s: np.ndarray
    leg_s: np.ndarray
    dwell_s: float

    @property
    def duration_s(self) -> float:
        """From the start to the arrival at the last waypoint (s)."""
        return float(self.leg_start_s[-1] + self.leg_s[-1])

    def at(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The focal point (``(n, 3)`` mm), its speed (``(n,)`` mm/s) and the leg index (``(n,)``,
        -1 before the first leg starts) at the times ``t_s`` (s, from the start; clipped to it)."""
        t = np.clip(np.atleast_1d(np.asarray(t_s, dtype=np.float64)), 0.0, self.duration_s)
        leg = np.searchsorted(self.leg_start_s, t, side="right") - 1
        k = np.clip(leg, 0, len(self.leg_s) - 1)
        u = np.clip((t - self.leg_start_s[k]) / self.leg_s[k], 0.0, 1.0)
        s = u ** 3 * (10 - 15 * u + 6 * u ** 2)
        ds_du = 30 * u ** 2 * (1 - u) ** 2
        a, b = self.waypoints_mm[k], self.waypoints_mm[k + 1]
        d = np.linalg.norm(b - a, axis=1)
        points = np.where(leg[:, None] < 0, self.waypoints_mm[0], a + s[:, None] * (b - a))
        speed = np.where(leg < 0, 0.0, ds_du * d / self.leg_s[k])
        return points, speed, leg

    def poses(self, t_s) -> np.ndarray:
        """``T_carm_transducer`` ``(n, 4, 4)`` at the times ``t_s``: the start's orientation, the
        focal point on the path."""
        points, _, _ = self.at(t_s)
        out = np.repeat(self.T_centre[None], len(points), axis=0)
        out[:, :3, 3] = points
        return out


def robot_path(T_centre, duration_s: float, *, radius_mm: float = 12.5, max_speed_mm_s: float = 10.0,
               dwell_s: float = 1.0) -> RobotPath:
    """The robot's tour of the zone about ``T_centre`` that lasts at least ``duration_s`` and ends on
    the centre (order and minimum-jerk profile: docs/study-sections.md, "06"); a leg of length ``d``
    takes ``1.875 d / max_speed_mm_s`` seconds.

    Args:
        T_centre: the pose at the zone's centre, 4x4 ``T_carm_transducer`` (mm).
        duration_s: the shortest tour, s (> 0).
        radius_mm: the zone's radius, mm (> 0): the margin points' distance from the centre.
        max_speed_mm_s: the peak speed of each leg, mm/s (> 0).
        dwell_s: how long each waypoint is held first, s (>= 0).

    Returns:
        The :class:`RobotPath`.

    Raises:
        ValueError: a bad duration, radius, speed or dwell, or ``T_centre`` not a finite 4x4.
    """
    duration_s = check_positive(duration_s, "duration_s", unit="s")
    radius_mm = check_positive(radius_mm, "radius_mm", unit="mm")
    max_speed_mm_s = check_positive(max_speed_mm_s, "max_speed_mm_s", unit="mm/s")
    if isinstance(dwell_s, bool) or not isinstance(dwell_s, (int, float)) or not (math.isfinite(dwell_s)
                                                                                  and dwell_s >= 0):
        raise ValueError(f"dwell_s must be a finite pause >= 0 s, got {dwell_s!r}")
    T_centre = np.asarray(T_centre, dtype=np.float64)
    if T_centre.shape != (4, 4) or not np.all(np.isfinite(T_centre)):
        raise ValueError(f"T_centre must be a finite 4x4 T_carm_transducer (mm), got shape {T_centre.shape}")
    margins = {name: T[:3, 3] for name, T in margin_positions(T_centre, radius_mm).items()}
    names, starts, legs = ["centre"], [], []
    t, i = 0.0, 1
    while True:
        name = MARGIN_TOUR[i % len(MARGIN_TOUR)]
        d = float(np.linalg.norm(margins[name] - margins[names[-1]]))
        starts.append(t + dwell_s)
        legs.append(1.875 * d / max_speed_mm_s)
        names.append(name)
        t = starts[-1] + legs[-1]
        i += 1
        if t >= duration_s and name == "centre":  # end the tour back on the centre
            break
    return RobotPath(T_centre=T_centre, names=tuple(names), waypoints_mm=np.array([margins[n] for n in names]),
                     leg_start_s=np.array(starts), leg_s=np.array(legs), dwell_s=float(dwell_s))


@dataclass(frozen=True)
class MovingCine:
    """Where :func:`write_moving_cine` put the cine (paths) and what it is.

    Args:
        folder: the cine's folder.
        views: its ``views.json``.
        frames: per frame, its objects in plane order (``((A, B), ...)``), the order a sender
            streams them.
        times_s: each frame's time from the first, s.
        fps: the frame rate, frames/s.
        acquired: the first frame's ``AcquisitionDateTime``.
        truth: ``truth.json`` (never read by the receiver).
        manifest: ``cine.json``.
    """

    folder: Path
    views: Path
    frames: tuple
    times_s: np.ndarray
    fps: float
    acquired: _dt.datetime
    truth: Path
    manifest: Path

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def frame_at(self, acquired: _dt.datetime) -> int:
        """The frame index of an acquisition time (the nearest frame)."""
        return int(round((acquired - self.acquired).total_seconds() * self.fps))

    def read_truth(self) -> dict:
        """The truth as arrays: ``time_s`` (n,), ``T_carm_transducer`` (n, 4, 4), ``T_base_flange``
        (n, 4, 4), ``focal_point_mm`` (n, 3), ``speed_mm_s`` (n,), ``leg`` (n,), ``waypoints_mm``,
        ``waypoint_names``, ``radius_mm`` and the set-up's 4x4 transforms."""
        data = json.loads(self.truth.read_text(encoding="utf-8"))
        return {k: (np.asarray(v) if isinstance(v, list) and k != "waypoint_names" else v) for k, v in data.items()}


def write_moving_cine(folder: str | os.PathLike, *, seed: int, duration_s: float = 60.0, fps: float = 7.5,
                      radius_mm: float = 12.5, max_speed_mm_s: float = 10.0, dwell_s: float = 1.0,
                      config: TargetingStudyConfig | None = None, render_spacing_mm: float = 0.25,
                      views: tuple[View, View] | None = None,
                      progress: Callable[[int, int], object] | None = None) -> MovingCine:
    """Write the moving cine (docs/study-sections.md, "06") into ``folder``; returns its paths.

    Args:
        seed: every draw (the set-up, the scene, the physical transducer, the photon noise).
        duration_s: the cine's length (s); ``round(duration_s * fps)`` frames.
        fps: the C-arm's frame rate (frames per second; 7.5 and 15 are the usual fluoroscopy rates).
        radius_mm, max_speed_mm_s, dwell_s: the tour (:func:`robot_path`).
        config: the set-up and rendering (default: the targeting study's, phantom background).
        render_spacing_mm: the rendered models' point spacing (mm; as
            :func:`histostudy.study.your_data.lab_dataset.write_lab_dataset`).
        views: the biplane (default :func:`~histostudy.imaging.default_biplane`, full size: the
            shipped learned stages need it).
        progress: called as ``progress(frames_written, n_frames)`` after each frame.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    fps = check_positive(fps, "fps", unit="frames/s")
    duration_s = check_positive(duration_s, "duration_s", unit="s")
    n = int(round(duration_s * fps))
    if n < 1:
        raise ValueError(f"duration_s * fps must give at least one frame, got duration_s={duration_s!r}, fps={fps!r}")
    config = TargetingStudyConfig(n_experiments=1, background="phantom") if config is None else config
    biplane = tuple(default_biplane() if views is None else views)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)

    s_truth, s_scene, s_physical, s_render = np.random.SeedSequence(seed).spawn(4)
    truth = draw_ground_truth(np.random.default_rng(s_truth), config)
    scene = LabScene.draw(config, biplane, rng_scene=np.random.default_rng(s_scene),
                          rng_physical=np.random.default_rng(s_physical), render_spacing_mm=render_spacing_mm)
    rng_render = np.random.default_rng(s_render)
    T_centre = truth.T_carm_transducer(forward_kinematics(start_joints(truth)))
    path = robot_path(T_centre, max(n - 1, 1) / fps, radius_mm=radius_mm, max_speed_mm_s=max_speed_mm_s,
                      dwell_s=dwell_s)
    times = np.arange(n) / fps
    focal, speed, leg = path.at(times)
    poses = path.poses(times)
    T_base_carm, T_transducer_flange = invert_transform(truth.T_carm_base), invert_transform(truth.T_flange_transducer)
    flanges = [T_base_carm @ T @ T_transducer_flange for T in poses]

    frames = []
    for k, T in enumerate(poses):
        acquired = T0 + _dt.timedelta(microseconds=round(1e6 * times[k]))
        pair = scene.render_pair(T, rng_render)
        frames.append(tuple(
            write_xa(out / "frames" / view.name / f"{k:05d}.dcm", view, detector_counts(image),
                     uid_seed=f"moving-cine-{seed}", instance_number=k + 1, acquisition_time=acquired)
            for view, image in zip(biplane, pair)))
        if progress is not None:
            progress(k + 1, n)

    views_path = save_views(out / "views.json", biplane)
    truth_path = atomic_write_json(out / "truth.json", to_jsonable({
        "note": "the synthetic truth, which the receiver never reads: for measuring errors only",
        "time_s": times, "T_carm_transducer": poses, "T_base_flange": flanges, "focal_point_mm": focal,
        "speed_mm_s": speed, "leg": leg, "waypoints_mm": path.waypoints_mm, "waypoint_names": list(path.names),
        "radius_mm": float(radius_mm), "T_carm_base": truth.T_carm_base,
        "T_flange_transducer": truth.T_flange_transducer, "T_carm_phantom": truth.T_carm_phantom,
        "physical_focal_point_mm": scene.physical.focal_point_mm}))
    manifest = atomic_write_json(out / "cine.json", to_jsonable({
        "format": CINE_FORMAT, "seed": int(seed), "fps": fps, "n_frames": n, "duration_s": float(duration_s),
        "radius_mm": float(radius_mm), "max_speed_mm_s": float(max_speed_mm_s), "dwell_s": float(dwell_s),
        "render_spacing_mm": float(render_spacing_mm), "acquired": T0.isoformat(), "views": "views.json",
        "planes": [v.name for v in biplane],
        "frames": [[str(p.relative_to(out)) for p in pair] for pair in frames], "truth": "truth.json",
        "what": "single-frame DICOM XA objects of the physical transducer carried by the robot between the "
                "margin points of the study, one per plane and frame, timed by AcquisitionDateTime"}))
    return MovingCine(folder=out, views=views_path, frames=tuple(frames), times_s=times, fps=fps, acquired=T0,
                      truth=truth_path, manifest=manifest)


def load_moving_cine(folder: str | os.PathLike) -> MovingCine:
    """A cine :func:`write_moving_cine` wrote, read from its ``cine.json``.

    Args:
        folder: the cine's folder.

    Returns:
        The :class:`MovingCine`.

    Raises:
        FileNotFoundError: no ``cine.json`` in ``folder``.
        ValueError: a ``cine.json`` of another format.
    """
    out = Path(folder)
    manifest = out / "cine.json"
    if not manifest.is_file():
        raise FileNotFoundError(f"folder {str(out)!r} holds no cine.json (see write_moving_cine)")
    data = json.loads(manifest.read_text(encoding="utf-8"))
    if data.get("format") != CINE_FORMAT:
        raise ValueError(f"{manifest} has format {data.get('format')!r}, expected {CINE_FORMAT!r}")
    fps = float(data["fps"])
    return MovingCine(folder=out, views=out / data["views"],
                      frames=tuple(tuple(out / p for p in pair) for pair in data["frames"]),
                      times_s=np.arange(int(data["n_frames"])) / fps, fps=fps,
                      acquired=_dt.datetime.fromisoformat(data["acquired"]), truth=out / data["truth"],
                      manifest=manifest)
