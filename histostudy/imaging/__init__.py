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

from histostudy.core import renamed_attributes
from . import (anatomy as _anatomy, carm as _carm, carm_errors as _carm_errors, cbct as _cbct, frame as _frame,
               io as _io, render as _render, rtk_projector as _rtk_projector, volume as _volume)
from .anatomy import MIXED_ABDOMEN_PROBABILITY, random_abdomen, random_background, random_phantom_setup
from .anatomy import Difference, Intersection
from .anatomy import AbdomenSpec, PhantomSceneSpec
from .anatomy import Anatomy, Background, StaticBackground
from .anatomy import Box, Ellipsoid, EllipticCylinder, Primitive
from .carm import View, default_biplane, load_views, save_views
from .carm_errors import GRAVITY_CARM, displaced_view, miscalibrated_view
from .cbct import PhantomSpec, check_target, phantom_mask, phantom_values, phantom_volume, random_target, simulate_cbct
from .io import REQUIRED_GEOMETRY_TAGS, gantry_from_dicom
from .io import SLICE_POSITION_RTOL
from .io import XA_SOP_CLASS_UID, detector_counts, write_xa, xa_dataset
from .io import (RECEIVABLE_TRANSFER_SYNTAXES, X_RAY_SOP_CLASSES, XRayObjectRejected, check_sop_class,
                 check_xray_object, read_dicom_file, xray_pixels)
from .frame import Frame, line_integrals_from_pixels, load_frame
from .io import save_volume_nifti
from .render import add_poisson_noise, background_line_integrals, render_frame, render_labels, render_line_integrals
from .render import check_device, mark_nearest_pixels_compiled, splat_compiled, splat_points, splat_torch
from .render import BACKGROUNDS, FrameRenderConfig
from .render import TorchSplatter, poisson_noise_torch
from .render import FrameMemo, shared_frames
from .rtk_projector import forward_project, render_frame_rtk, rtk_available, rtk_geometry, voxelise_model
from .volume import Volume, check_mask, check_volume, vector3_mm
from .volume import LPS_FROM_RAS, lps_from_ras, ras_from_lps
from .io import SUPPORTED_FORMATS, load_volume
from .io import AXIS_TOLERANCE

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_anatomy.__all__, *_carm.__all__, *_carm_errors.__all__, *_cbct.__all__,
                              *_frame.__all__, *_io.__all__, *_render.__all__, *_rtk_projector.__all__,
                              *_volume.__all__]))

# the 0.1.0 name, deprecated (CHANGELOG.md)
__getattr__ = renamed_attributes(globals(), {'RenderSettings': 'FrameRenderConfig', 'AbdomenParams': 'AbdomenSpec', 'PhantomParams': 'PhantomSceneSpec'})
