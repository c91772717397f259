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

from . import anatomy as _anatomy
from . import carm as _carm
from . import carm_errors as _carm_errors
from . import cbct as _cbct
from . import frame as _frame
from . import io as _io
from . import render as _render
from . import rtk_projector as _rtk_projector
from . import volume as _volume
from .anatomy import (
               MIXED_ABDOMEN_PROBABILITY,
               AbdomenSpec,
               Anatomy,
               Background,
               Box,
               Difference,
               Ellipsoid,
               EllipticCylinder,
               Intersection,
               PhantomSceneSpec,
               Primitive,
               StaticBackground,
               random_abdomen,
               random_background,
               random_phantom_setup,
)
from .carm import View, default_biplane, load_views, save_views
from .carm_errors import GRAVITY_CARM, displaced_view, miscalibrated_view
from .cbct import PhantomSpec, check_target, phantom_mask, phantom_values, phantom_volume, random_target, simulate_cbct
from .frame import Frame, line_integrals_from_pixels, load_frame
from .io import (
               AXIS_TOLERANCE,
               RECEIVABLE_TRANSFER_SYNTAXES,
               REQUIRED_GEOMETRY_TAGS,
               SLICE_POSITION_RTOL,
               SUPPORTED_FORMATS,
               X_RAY_SOP_CLASSES,
               XA_SOP_CLASS_UID,
               XRayObjectRejected,
               check_sop_class,
               check_xray_object,
               detector_counts,
               gantry_from_dicom,
               load_volume,
               read_dicom_file,
               save_volume_nifti,
               write_xa,
               xa_dataset,
               xray_pixels,
)
from .render import (
               BACKGROUNDS,
               FrameMemo,
               FrameRenderConfig,
               TorchSplatter,
               add_poisson_noise,
               background_line_integrals,
               check_device,
               mark_nearest_pixels_compiled,
               poisson_noise_torch,
               render_frame,
               render_labels,
               render_line_integrals,
               shared_frames,
               splat_compiled,
               splat_points,
               splat_torch,
)
from .rtk_projector import forward_project, render_frame_rtk, rtk_available, rtk_geometry, voxelise_model
from .volume import LPS_FROM_RAS, Volume, check_mask, check_volume, lps_from_ras, ras_from_lps, vector3_mm

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_anatomy.__all__, *_carm.__all__, *_carm_errors.__all__, *_cbct.__all__,
                              *_frame.__all__, *_io.__all__, *_render.__all__, *_rtk_projector.__all__,
                              *_volume.__all__]))

# the 0.1.0 name, deprecated (CHANGELOG.md)
