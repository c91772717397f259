"""The imaging chain (§II-A, §II-B.2, §II-D): C-arm views and their projection, eq. 1-2 (``carm``), and
how a lab's geometry departs from its calibration (``carm_errors``); frames with their geometry
(``frame``); synthetic fluoroscopy of the transducer (``render``) over random scenes (``anatomy``);
RTK's projector as an independent check (``rtk_projector``); CBCT volumes (``volume``), the phantom
and its simulated CBCT (``cbct``); and a lab's image files (``io``). See docs/imaging.md."""

from .anatomy import Anatomy, random_background
from .carm import View, default_biplane, load_views, save_views
from .cbct import PhantomSpec, check_target, phantom_mask, phantom_volume, random_target, simulate_cbct
from .frame import Frame, line_integrals_from_pixels, load_frame
from .io import detector_counts, load_volume, save_volume_nifti, write_xa
from .render import (
    BACKGROUNDS,
    SPLAT_DEVICES,
    FrameRenderConfig,
    add_poisson_noise,
    background_line_integrals,
    render_frame,
    render_labels,
    render_line_integrals,
    shared_frames,
)
from .rtk_projector import render_frame_rtk, rtk_available
from .volume import Volume, check_mask, check_volume, lps_from_ras, ras_from_lps, vector3_mm

__all__ = [
    "BACKGROUNDS",
    "Anatomy",
    "Frame",
    "FrameRenderConfig",
    "PhantomSpec",
    "SPLAT_DEVICES",
    "View",
    "Volume",
    "add_poisson_noise",
    "background_line_integrals",
    "check_mask",
    "check_target",
    "check_volume",
    "default_biplane",
    "detector_counts",
    "line_integrals_from_pixels",
    "load_frame",
    "load_views",
    "load_volume",
    "lps_from_ras",
    "phantom_mask",
    "phantom_volume",
    "random_background",
    "random_target",
    "ras_from_lps",
    "render_frame",
    "render_frame_rtk",
    "render_labels",
    "render_line_integrals",
    "rtk_available",
    "save_views",
    "save_volume_nifti",
    "shared_frames",
    "simulate_cbct",
    "vector3_mm",
    "write_xa",
]
