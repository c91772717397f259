"""Which segmenter and orientation source :func:`~.estimate.estimate_pose` uses when none is given
(§II-B.2 U-Net, §II-B.4 VGG19 and the inner-boundary conic): the shipped learned stages where their
manifests' validation figures are good enough, else the oracles of the synthetic study.
"""

from __future__ import annotations

import functools
import warnings

from histostudy.learning import (
    MODELS_DIR,
    OracleOrientation,
    OracleSegmenter,
    OrientationSource,
    Segmenter,
    default_segmenter,
)

from .conic_orientation import default_orientation

__all__ = ["LEARNED_STAGE_REQUIREMENTS", "default_stages", "learned_stage_shortfalls"]

#: What a shipped network's manifest must show on its validation split before
#: :func:`~.estimate.estimate_pose` uses it by default: a network trained too briefly to be useful
#: (e.g. a VGG19 whose azimuth error is that of a guess, about 90 deg) would otherwise send every
#: default estimate astray.
#: The VGG19 only starts the initialisation's searches, which tolerate large errors: with its
#: per-view direction starts, a VGG19 with validation MAE 25.6 deg azimuth and 11.4 deg elevation
#: (the one shipped before the (cos, sin) regressor) gave the oracle orientation's pose on 16 of 16
#: poses of notebook 04's setting (focal error 0.19 mm either way, oracle labels), hence 30 deg.
LEARNED_STAGE_REQUIREMENTS = {"unet_min_pixel_accuracy": 0.95, "vgg_max_angle_mae_deg": 30.0}


def _validation(stage) -> dict:
    manifest = getattr(stage, "manifest", None) or {}
    return manifest.get("validation", {}) or {}


def learned_stage_shortfalls(segmenter, orientation) -> list[str]:
    """Why these learned stages fall short of :data:`LEARNED_STAGE_REQUIREMENTS` (§II-B.2 U-Net, §II-B.4 VGG19).

    Judged on their manifests' validation figures (``manifest["validation"]``).

    Args:
        segmenter: the shipped U-Net segmenter, or None for a missing network.
        orientation: the shipped orientation source (its VGG19's manifest), or None for a missing one.

    Returns:
        One sentence per shortfall (the figure and its bound); empty when both meet the requirements.
    """
    reasons = []
    if segmenter is None:
        reasons.append(f"no usable shipped U-Net (unet_standard.safetensors and its manifest, looked for in "
                       f"{MODELS_DIR})")
    else:
        accuracy = _validation(segmenter).get("pixel_accuracy", float("nan"))
        if not accuracy >= LEARNED_STAGE_REQUIREMENTS["unet_min_pixel_accuracy"]:
            reasons.append(f"the shipped U-Net's validation pixel accuracy {accuracy:.3f} is below "
                           f"{LEARNED_STAGE_REQUIREMENTS['unet_min_pixel_accuracy']}")
    if orientation is None:
        reasons.append(f"no usable shipped VGG19 (vgg19_standard.safetensors and its manifest, looked for in "
                       f"{MODELS_DIR})")
    else:
        v = _validation(orientation)
        worst = max(v.get("azimuth_mae_deg", float("nan")), v.get("elevation_mae_deg", float("nan")))
        if not worst <= LEARNED_STAGE_REQUIREMENTS["vgg_max_angle_mae_deg"]:
            reasons.append(f"the shipped VGG19's validation angle MAE {worst:.1f} deg exceeds "
                           f"{LEARNED_STAGE_REQUIREMENTS['vgg_max_angle_mae_deg']} deg")
    return reasons


@functools.lru_cache(maxsize=1)
def default_stages() -> tuple[Segmenter, OrientationSource]:
    """The segmenter and orientation source :func:`~.estimate.estimate_pose` uses when none is given.

    The learned stages shipped in ``data/models`` (:func:`histostudy.learning.default_segmenter`, the
    U-Net of §II-B.2, and :func:`~.conic_orientation.default_orientation`, §II-B.4) where their
    weights are present, pass their hash and configuration check, and their manifests' validation
    figures meet :data:`LEARNED_STAGE_REQUIREMENTS`; otherwise the oracles (synthetic frames only),
    with a warning that says why. Loaded once per process. Pass ``segmenter=`` / ``orientation=`` to
    ``estimate_pose`` to choose explicitly.

    Args:
        (none)

    Returns:
        ``(segmenter, orientation)``: the shipped stages, or ``OracleSegmenter()`` and
        ``OracleOrientation()``.
    """
    segmenter = default_segmenter()
    orientation = default_orientation(segmenter)  # its conic initialiser reads this U-Net's labels
    reasons = learned_stage_shortfalls(segmenter, orientation)
    if reasons:
        warnings.warn("estimate_pose: " + "; ".join(reasons) + " — using the oracle stages, which need "
                      "synthetic frames", stacklevel=3)
        return OracleSegmenter(), OracleOrientation()
    assert segmenter is not None and orientation is not None
    return segmenter, orientation
