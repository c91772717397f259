"""The histotripsy transducer (§II-B.1, §IV): its spec, feature classes and label priority
(``spec``); the digital model, point clouds per feature class (``digital``, sampled by
``sampling``); the physical model the synthetic frames are rendered from, with the manufacturing
mismatch of §IV (``physical``); models from and to a lab's CAD meshes (``mesh``, ``mesh_export``);
its half-turn symmetry (``symmetry``); and the paper's set-up pose (``placement``)."""

from .digital import TransducerModel
from .mesh_export import export_meshes
from .physical import ManufacturingDeviation
from .placement import pose_facing
from .spec import FEATURE_CLASSES, LABEL_PRIORITY, Feature, TransducerSpec, check_label_image
from .symmetry import HALF_TURN, half_turn_symmetric

__all__ = [
    "FEATURE_CLASSES",
    "HALF_TURN",
    "LABEL_PRIORITY",
    "Feature",
    "ManufacturingDeviation",
    "TransducerModel",
    "TransducerSpec",
    "check_label_image",
    "export_meshes",
    "half_turn_symmetric",
    "pose_facing",
]
