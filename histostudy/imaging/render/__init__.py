"""Synthetic fluoroscopy of the transducer (§II-B.2): the numpy reference renderer (``_reference``)
and its settings (``_settings``), the same splat compiled on the CPU (``_splat_kernels``) or on a
torch device (``_torch``) as ``_device`` picks, and a scope that renders each distinct frame once
(``_memo``). See docs/imaging.md."""

from ._memo import shared_frames
from ._reference import add_poisson_noise, background_line_integrals, render_frame, render_labels, render_line_integrals
from ._settings import BACKGROUNDS, SPLAT_DEVICES, FrameRenderConfig
from ._torch import TorchSplatter, poisson_noise_torch

__all__ = [
    "BACKGROUNDS",
    "FrameRenderConfig",
    "SPLAT_DEVICES",
    "TorchSplatter",
    "add_poisson_noise",
    "background_line_integrals",
    "poisson_noise_torch",
    "render_frame",
    "render_labels",
    "render_line_integrals",
    "shared_frames",
]
