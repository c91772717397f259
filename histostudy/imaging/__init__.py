"""The imaging chain (§II-A, §II-B.2, §II-D): C-arm views and their projection, eq. 1-2 (``carm``),
and how a lab's geometry differs from its calibration (``carm_errors``),
with the geometry a DICOM XA object records (``dicom_geometry``) and XA objects written as a C-arm
writes them (``dicom_xa``); images with their geometry, and a detector's stored values as line
integrals (``frame``); synthetic fluoroscopy of the transducer (``render``, the numpy reference; compiled on the CPU
(``splat_kernels``) or on a torch device, a batch at a time (``render_torch``), as ``render_device`` picks; its dose, splatting and scene,
shared by every configuration that renders, in ``render_settings``) over random abdomen and phantom
scenes (``anatomy``, their ranges in ``anatomy_params``); a scene and its line-integral image
(``anatomy_scene``), built of analytic solids (``anatomy_shapes``), their composites
(``anatomy_csg``) and the ray algebra they share (``anatomy_rays``); RTK's Joseph projector as an
independent check (``rtk_projector``); CBCT volumes (``volume``), the layered phantom and its
simulated CBCT (``cbct``); and volume files (``volume_io``, which hands NIfTI to ``nifti_io`` and
DICOM to ``dicom_io``, both laid onto the Volume grid by ``volume_io_grid``).
"""

from . import (anatomy as _anatomy, anatomy_csg as _anatomy_csg, anatomy_params as _anatomy_params,
               anatomy_scene as _anatomy_scene, anatomy_shapes as _anatomy_shapes, carm as _carm, carm_errors as _carm_errors,
               cbct as _cbct,
               dicom_geometry as _dicom_geometry, dicom_io as _dicom_io, dicom_xa as _dicom_xa, frame as _frame, nifti_io as _nifti_io,
               render as _render, render_device as _render_device, render_settings as _render_settings,
               render_torch as _render_torch, rtk_projector as _rtk_projector,
               volume as _volume, volume_io as _volume_io, volume_io_grid as _volume_io_grid)
from .anatomy import MIXED_ABDOMEN_PROBABILITY, random_abdomen, random_background, random_phantom_setup
from .anatomy_csg import Difference, Intersection
from .anatomy_params import AbdomenParams, PhantomParams
from .anatomy_scene import Anatomy, Background, StaticBackground
from .anatomy_shapes import Box, Ellipsoid, EllipticCylinder, Primitive
from .carm import View, default_biplane, load_views, save_views
from .carm_errors import GRAVITY_CARM, displaced_view, miscalibrated_view
from .cbct import PhantomSpec, check_target, phantom_mask, phantom_values, phantom_volume, random_target, simulate_cbct
from .dicom_geometry import REQUIRED_GEOMETRY_TAGS, gantry_from_dicom
from .dicom_io import SLICE_POSITION_RTOL
from .dicom_xa import XA_SOP_CLASS_UID, detector_counts, write_xa, xa_dataset
from .frame import Frame, line_integrals_from_pixels, load_frame
from .nifti_io import save_volume_nifti
from .render import add_poisson_noise, background_line_integrals, render_frame, render_labels, render_line_integrals
from .render_device import check_device, mark_nearest_pixels_compiled, splat_compiled, splat_points, splat_torch
from .render_settings import BACKGROUNDS, RenderSettings
from .render_torch import TorchSplatter, poisson_noise_torch
from .rtk_projector import forward_project, render_frame_rtk, rtk_available, rtk_geometry, voxelise_model
from .volume import Volume, check_mask, check_volume, vector3_mm
from .volume_io import SUPPORTED_FORMATS, load_volume
from .volume_io_grid import AXIS_TOLERANCE

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_anatomy.__all__, *_anatomy_csg.__all__, *_anatomy_params.__all__,
                              *_anatomy_scene.__all__, *_anatomy_shapes.__all__, *_carm.__all__, *_carm_errors.__all__, *_cbct.__all__,
                              *_dicom_geometry.__all__, *_dicom_io.__all__, *_dicom_xa.__all__, *_frame.__all__, *_nifti_io.__all__,
                              *_render.__all__, *_render_device.__all__, *_render_settings.__all__, *_render_torch.__all__, *_rtk_projector.__all__, *_volume.__all__,
                              *_volume_io.__all__, *_volume_io_grid.__all__]))
