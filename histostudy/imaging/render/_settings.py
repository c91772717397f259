"""How a synthetic fluoroscopic frame is rendered (§II-B.2): dose, splatting and the scene behind, declared
once in :class:`FrameRenderConfig` for every configuration that renders frames; defaults are the paper's."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

from histostudy.core import check_count, check_positive, is_finite_real

__all__ = ["BACKGROUNDS", "SPLAT_DEVICES", "FrameRenderConfig"]

#: Scenes behind the transducer: the phantom set-up, a procedural abdomen, the paper's mix of the
#: two (156:56, :func:`~histostudy.imaging.anatomy._random.random_background`), or nothing.
BACKGROUNDS = ("phantom", "abdomen", "mixed", "none")

#: Where a frame's splatting may run (``splat_device``): None or ``"numpy"``, the numpy reference;
#: ``"cpu"``, the compiled kernel; ``"cuda"``, torch on the GPU; ``"auto"``, CUDA where torch sees
#: one, else compiled (docs/imaging.md, "Splatting").
SPLAT_DEVICES = (None, "numpy", "cpu", "cuda", "auto")


@dataclass(frozen=True)
class FrameRenderConfig:
    """Rendering of a synthetic frame (§II-B.2); see :func:`~histostudy.imaging.render._reference.render_frame`.

    Attributes:
        photons_per_pixel: unattenuated photons per pixel for the Poisson noise; None for none.
        n_splats: splats per model point (paper: 16).
        splat_sigma_mm: standard deviation of the splat jitter, mm (paper: 0.5 mm).
        background: the scene behind the transducer, one of :data:`BACKGROUNDS`.
        splat_device: where the splatting runs, one of :data:`SPLAT_DEVICES` (``"numpy"`` is kept
            as None). The renderers draw the same distribution, not the same numbers: a frame
            belongs to its resolved device (:meth:`resolved_device`).
    """

    photons_per_pixel: float | None = 5e4
    n_splats: int = 16
    splat_sigma_mm: float = 0.5
    background: str = "phantom"
    splat_device: str | None = None

    def __post_init__(self):
        check_photons_per_pixel(self.photons_per_pixel, allow_none=True)
        check_n_splats(self.n_splats)
        check_splat_sigma_mm(self.splat_sigma_mm)
        if self.background not in BACKGROUNDS:
            raise ValueError(f"background must be one of {BACKGROUNDS}, got {self.background!r}")
        if not (self.splat_device is None or isinstance(self.splat_device, str)) \
                or self.splat_device not in SPLAT_DEVICES:
            raise ValueError(f"splat_device must be one of {SPLAT_DEVICES}, got {self.splat_device!r}")
        if self.splat_device == "numpy":
            object.__setattr__(self, "splat_device", None)

    def resolved_device(self) -> str | None:
        """The device the splatting runs on here: ``splat_device`` with ``"auto"`` resolved (CUDA
        where torch sees it, else ``"cpu"``); None for the numpy reference."""
        if self.splat_device != "auto":
            return self.splat_device
        import torch  # only "auto" needs torch

        return "cuda" if torch.cuda.is_available() else "cpu"

    def frame_kwargs(self) -> dict:
        """The keyword arguments of :func:`~histostudy.imaging.render._reference.render_frame` these settings fix."""
        return {"photons_per_pixel": self.photons_per_pixel, "n_splats": self.n_splats,
                "splat_sigma_mm": self.splat_sigma_mm, "device": self.resolved_device()}


# The checks of each setting, here once; render_frame and add_poisson_noise call them too.

@overload
def check_photons_per_pixel(value, *, allow_none: Literal[False]) -> float: ...


@overload
def check_photons_per_pixel(value, *, allow_none: bool) -> float | None: ...


def check_photons_per_pixel(value, *, allow_none: bool) -> float | None:
    """``value`` as unattenuated photons per pixel (finite, > 0; None for no noise where allowed)."""
    if value is None and allow_none:
        return None
    if not is_finite_real(value) or value <= 0:
        expected = "a finite number > 0 or None" if allow_none else "a finite number > 0"
        raise ValueError(f"photons_per_pixel must be {expected} (photons per pixel), got {value!r}")
    return float(value)


def check_n_splats(value) -> int:
    """``value`` as a number of splats per model point (an integer >= 1)."""
    return check_count(value, "n_splats")


def check_splat_sigma_mm(value) -> float:
    """``value`` as the splat jitter's standard deviation (finite, >= 0, mm)."""
    return check_positive(value, "splat_sigma_mm", allow_zero=True, unit="mm")

