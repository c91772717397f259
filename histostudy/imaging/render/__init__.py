"""Virtual x-ray projections of the transducer model (§II-B.2).

The numpy reference renderer (``_reference``), its settings (``_settings``), and the same splat on a
device: compiled CPU kernels (``_splat_kernels``), the torch/CUDA splatter (``_torch``) and the entry
points that choose between them (``_device``); a scope that renders each distinct frame once
(``_memo``).
"""

from . import _device, _memo, _reference, _settings, _torch
from ._device import check_device, mark_nearest_pixels_compiled, splat_compiled, splat_points, splat_torch
from ._memo import FrameMemo, shared_frames
from ._reference import add_poisson_noise, background_line_integrals, render_frame, render_labels, render_line_integrals
from ._settings import BACKGROUNDS, FrameRenderConfig
from ._torch import TorchSplatter, poisson_noise_torch

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_device.__all__, *_memo.__all__, *_reference.__all__, *_settings.__all__, *_torch.__all__]))

# the 0.1.0 name, deprecated (CHANGELOG.md)
