"""Notebook 06's parameters, checked (§II-B to §II-D on a lab's files): :class:`YourDataConfig`."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from histostudy.core import check_count, check_positive, is_finite_real

from ..section import SectionConfig, check_splat_device
from ..section import check_bool as _check_bool

SECTION = "06_your_data"
TITLE = "Your own data: frames, calibration, target and robot (§II-B to §II-D on a lab's files)"

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("data_dir", "target_mm", "pose_spacing_mm", "splat_device", "robot_host", "dry_run",
                       "stream_cine", "moving_cine_s", "moving_cine_fps", "moving_cine_speed_mm_s", "max_queued_pairs")


def _check_optional_count(value, name: str) -> int | None:
    if value is None:
        return None
    try:
        return check_count(value, name)
    except ValueError:
        raise ValueError(f"{name} must be None or an integer >= 1, got {value!r}") from None


@dataclass(frozen=True)
class YourDataConfig(SectionConfig):
    """Notebook 06's parameters, checked; built from the parameters cell by
    ``YourDataConfig.from_parameters(globals())``. Numbers are kept as floats and ints, ``target_mm``
    as a tuple of 3 floats.

    Args:
        data_dir: the lab's folder; None: the lab-like dataset is generated.
        target_mm: the target (x, y, z) in the CBCT's world frame (the C-arm's), mm; None: the
            dataset's suggested target.
        n_cine_frames: frames of the generated cine (>= 1).
        max_tracked_frames: cine frames to track (>= 1); None: all.
        stream_cine: stream the cine through the DICOM receiver on loopback.
        moving_cine_s: seconds of the moving cine (>= 0; 0 skips it).
        moving_cine_fps: its frame rate, frames/s (> 0).
        moving_cine_speed_mm_s: the robot's peak speed between the margin points, mm/s (> 0).
        max_queued_pairs: pairs waiting for a pose beyond which the receiver drops the oldest
            (>= 1); None: keep all.
        photons_per_pixel: the generated frames' dose, photons per detector pixel (> 0).
        n_splats: splats per model point (>= 1).
        splat_sigma_mm: splat SD, mm (> 0).
        splat_device: where the generated frames are splatted, one of
            :data:`~histostudy.study.section.STUDY_SPLAT_DEVICES`.
        pose_spacing_mm: the transducer model's grid for the pose estimate, mm (> 0).
        robot_host: the UR controller's host name or address; None: no robot.
        dry_run: True: plan and check the move, move nothing.
        speed_mm_s: the move's linear speed, mm/s (> 0).

    Raises:
        ValueError: a bad value, naming the parameter, its value and what it must be (or, from
            ``from_parameters``, the parameters the mapping lacks).
    """

    NOTEBOOK = "06"
    RECORDED = RECORDED_PARAMETERS

    data_dir: str | os.PathLike | None
    target_mm: tuple | None
    n_cine_frames: int
    max_tracked_frames: int | None
    stream_cine: bool
    moving_cine_s: float
    moving_cine_fps: float
    moving_cine_speed_mm_s: float
    max_queued_pairs: int | None
    photons_per_pixel: float
    n_splats: int
    splat_sigma_mm: float
    splat_device: str
    pose_spacing_mm: float
    robot_host: str | None
    dry_run: bool
    speed_mm_s: float

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.data_dir is not None and not isinstance(self.data_dir, (str, os.PathLike)):
            raise ValueError(f"data_dir must be None or a folder path, got {self.data_dir!r}")
        if self.target_mm is not None:
            target = self.target_mm
            if isinstance(target, (str, bytes)) or np.ndim(target) != 1 or len(target) != 3 \
                    or not all(is_finite_real(v) for v in target):
                raise ValueError(f"target_mm must be None or 3 finite numbers (x, y, z in the CBCT's world frame, "
                                 f"mm), got {target!r}")
            put("target_mm", tuple(float(v) for v in target))
        put("n_cine_frames", check_count(self.n_cine_frames, "n_cine_frames"))
        for name in ("max_tracked_frames", "max_queued_pairs"):
            put(name, _check_optional_count(getattr(self, name), name))
        for name in ("stream_cine", "dry_run"):
            put(name, _check_bool(getattr(self, name), name))
        put("moving_cine_s", check_positive(self.moving_cine_s, "moving_cine_s", allow_zero=True, unit="s"))
        for name, unit in (("moving_cine_fps", "frames/s"), ("moving_cine_speed_mm_s", "mm/s"),
                           ("photons_per_pixel", "photons per pixel"), ("splat_sigma_mm", "mm"),
                           ("pose_spacing_mm", "mm"), ("speed_mm_s", "mm/s")):
            put(name, check_positive(getattr(self, name), name, unit=unit))
        put("n_splats", check_count(self.n_splats, "n_splats"))
        check_splat_device(self.splat_device)
        if self.robot_host is not None and (not isinstance(self.robot_host, str) or not self.robot_host.strip()):
            raise ValueError(f"robot_host must be None or the UR controller's host name or address, "
                             f"got {self.robot_host!r}")

    def render(self) -> dict:
        """The generated frames' dose, splatting and renderer (:class:`~histostudy.imaging.FrameRenderConfig`
        fields)."""
        return {"photons_per_pixel": self.photons_per_pixel, "n_splats": self.n_splats,
                "splat_sigma_mm": self.splat_sigma_mm, "splat_device": self.splat_device}
