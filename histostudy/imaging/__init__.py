"""The imaging chain (§II-A, §II-B.2, §II-D): C-arm views and their projection, eq. 1-2 (``carm``);
images with their geometry (``frame``); synthetic fluoroscopy of the transducer (``render``; its
dose, splatting and scene, shared by every configuration that renders, in ``render_settings``) over
random abdomen and phantom scenes (``anatomy``, their ranges in ``anatomy_params``); a scene and its
line-integral image (``anatomy_scene``), built of analytic solids (``anatomy_shapes``), their
composites (``anatomy_csg``) and the ray algebra they share (``anatomy_rays``); RTK's Joseph
projector as an independent check (``rtk_projector``); CBCT volumes (``volume``), the layered
phantom and its simulated CBCT (``cbct``); and volume files (``volume_io``, which hands NIfTI to
``nifti_io`` and DICOM to ``dicom_io``, both laid onto the Volume grid by ``volume_io_grid``).
"""

from .anatomy import MIXED_ABDOMEN_PROBABILITY, random_abdomen, random_background, random_phantom_setup
from .anatomy_csg import Difference, Intersection
from .anatomy_params import AbdomenParams, PhantomParams
from .anatomy_scene import Anatomy, Background, StaticBackground
from .anatomy_shapes import Box, Ellipsoid, EllipticCylinder, Primitive
from .carm import View, default_biplane, load_views, save_views
from .cbct import PhantomSpec, check_target, phantom_mask, phantom_values, phantom_volume, random_target, simulate_cbct
from .dicom_io import SLICE_POSITION_RTOL
from .frame import Frame, load_frame
from .nifti_io import save_volume_nifti
from .render import add_poisson_noise, background_line_integrals, render_frame, render_labels, render_line_integrals
from .render_settings import BACKGROUNDS, RenderSettings
from .rtk_projector import forward_project, render_frame_rtk, rtk_available, rtk_geometry, voxelise_model
from .volume import Volume, check_mask, check_volume, vector3_mm
from .volume_io import SUPPORTED_FORMATS, load_volume
from .volume_io_grid import AXIS_TOLERANCE

__all__ = [
    "AXIS_TOLERANCE",
    "AbdomenParams",
    "Anatomy",
    "BACKGROUNDS",
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
    "RenderSettings",
    "SLICE_POSITION_RTOL",
    "SUPPORTED_FORMATS",
    "StaticBackground",
    "View",
    "Volume",
    "add_poisson_noise",
    "background_line_integrals",
    "check_mask",
    "check_target",
    "check_volume",
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
    "vector3_mm",
    "voxelise_model",
]
