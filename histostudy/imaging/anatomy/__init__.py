"""Synthetic patient and phantom scenes, the backgrounds of the hybrid fluoroscopy frames (§II-B.2).

Random scenes (``_random``) built from primitives (``_shapes``), their set operations (``_csg``), the
parameter ranges they draw from (``_params``), the ray/primitive intersections (``_rays``) and the
scene that projects them (``_scene``); the random abdomen's parts (body, organs, spine, ribs,
gas) are built in ``_abdomen_parts``.
"""

from . import _abdomen_parts, _csg, _params, _random, _scene, _shapes
from ._csg import Difference, Intersection
from ._params import AbdomenSpec, PhantomSceneSpec
from ._random import MIXED_ABDOMEN_PROBABILITY, random_abdomen, random_background, random_phantom_setup
from ._scene import Anatomy, Background, StaticBackground
from ._shapes import Box, Ellipsoid, EllipticCylinder, Primitive

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_abdomen_parts.__all__, *_csg.__all__, *_params.__all__, *_random.__all__, *_scene.__all__, *_shapes.__all__]))

# the 0.1.0 name, deprecated (CHANGELOG.md)
