"""The histotripsy transducer (§II-B.1, §IV): its spec, feature classes, label priority and
quadrants (``spec``); the weighted point sampling of its cap, walls and screws (``sampling``); the
digital model, point clouds per feature class (``digital``); the physical model the synthetic frames
are rendered from, with the manufacturing mismatch of §IV (``physical``); a model sampled from a
lab's closed CAD meshes, ``TransducerModel.from_meshes`` (``mesh``), and the parametric model
written as such meshes (``mesh_export``); whether a model looks the same after a half turn about
its axis (``symmetry``); and the paper's set-up pose (``placement``).
"""

from . import digital as _digital
from . import mesh as _mesh
from . import mesh_export as _mesh_export
from . import physical as _physical
from . import placement as _placement
from . import spec as _spec
from . import symmetry as _symmetry
from .digital import TransducerModel
from .mesh import default_mesh_mu_per_mm
from .mesh_export import export_meshes
from .physical import ManufacturingDeviation
from .placement import pose_facing
from .spec import FEATURE_CLASSES, LABEL_PRIORITY, Feature, TransducerSpec, check_label_image, quadrant_index
from .symmetry import HALF_TURN, half_turn_symmetric

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_digital.__all__, *_mesh.__all__, *_mesh_export.__all__, *_physical.__all__,
                              *_placement.__all__, *_spec.__all__, *_symmetry.__all__]))
