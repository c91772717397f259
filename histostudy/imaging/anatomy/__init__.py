"""Random abdomen and phantom scenes, the backgrounds of the hybrid fluoroscopy frames (§II-B.2):
drawn in ``_random`` from the ranges of ``_params`` (the abdomen's parts in ``_abdomen_parts``), built
of analytic solids (``_shapes``) and their set operations (``_csg``) over a shared ray algebra
(``_rays``), and projected to line integrals by the scene (``_scene``). See docs/imaging.md."""

from ._random import random_background
from ._scene import Anatomy

__all__ = ["Anatomy", "random_background"]
