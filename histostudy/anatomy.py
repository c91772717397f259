"""Deprecated path: ``histostudy.anatomy`` moved to :mod:`histostudy.imaging` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.imaging import (AbdomenParams, Anatomy, Background, Box, Difference, Ellipsoid,
                                EllipticCylinder, Intersection, MIXED_ABDOMEN_PROBABILITY, PhantomParams,
                                Primitive, StaticBackground, random_abdomen, random_background,
                                random_phantom_setup)

__all__ = ["AbdomenParams", "Anatomy", "Background", "Box", "Difference", "Ellipsoid", "EllipticCylinder", "Intersection", "MIXED_ABDOMEN_PROBABILITY", "PhantomParams", "Primitive", "StaticBackground", "random_abdomen", "random_background", "random_phantom_setup"]

warnings.warn("histostudy.anatomy is deprecated: import from histostudy.imaging instead", DeprecationWarning, stacklevel=2)
