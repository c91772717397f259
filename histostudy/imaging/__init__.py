"""The imaging chain (§II-A, §II-B.2, §II-D): C-arm views and their projection, eq. 1-2 (``carm``);
images with their geometry (``frame``); synthetic fluoroscopy of the transducer (``render``) over
anatomy backgrounds and phantom scenes (``anatomy``); RTK's Joseph projector as an independent
check (``rtk_projector``); CBCT volumes (``volume``), the layered phantom and its simulated
CBCT (``cbct``); and volume files, DICOM and NIfTI (``volume_io``).
"""

from .anatomy import (AbdomenParams, Anatomy, Background, Box, Difference, Ellipsoid, EllipticCylinder, Intersection,
                      MIXED_ABDOMEN_PROBABILITY, PhantomParams, Primitive, StaticBackground, random_abdomen,
                      random_background, random_phantom_setup)
from .carm import View, default_biplane, load_views, save_views
from .cbct import PhantomSpec, check_target, phantom_mask, phantom_values, phantom_volume, random_target, simulate_cbct
from .frame import Frame, load_frame
from .render import add_poisson_noise, background_line_integrals, render_frame, render_labels, render_line_integrals
from .rtk_projector import forward_project, render_frame_rtk, rtk_available, rtk_geometry, voxelise_model
from .volume import Volume
from .volume_io import AXIS_TOLERANCE, SLICE_POSITION_RTOL, SUPPORTED_FORMATS, load_volume, save_volume_nifti

__all__ = [
    "AXIS_TOLERANCE",
    "AbdomenParams",
    "Anatomy",
    "Background",
    "Box",
    "Difference",
    "Ellipsoid",
    "EllipticCylinder",
    "Frame",
    "Intersection",
    "MIXED_ABDOMEN_PROBABILITY",
    "PhantomParams",
    "PhantomSpec",
    "Primitive",
    "SLICE_POSITION_RTOL",
    "SUPPORTED_FORMATS",
    "StaticBackground",
    "View",
    "Volume",
    "add_poisson_noise",
    "background_line_integrals",
    "check_target",
    "default_biplane",
    "forward_project",
    "load_frame",
    "load_views",
    "load_volume",
    "phantom_mask",
    "phantom_values",
    "phantom_volume",
    "random_abdomen",
    "random_background",
    "random_phantom_setup",
    "random_target",
    "render_frame",
    "render_frame_rtk",
    "render_labels",
    "render_line_integrals",
    "rtk_available",
    "rtk_geometry",
    "save_views",
    "save_volume_nifti",
    "simulate_cbct",
    "voxelise_model",
]
