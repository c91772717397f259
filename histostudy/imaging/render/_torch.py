"""Point splatting and quantum noise on a torch device, a batch of frames per call (§II-B.2): the numpy
reference's arithmetic, its jitter seeded per frame (docs/imaging.md, "Splatting")."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from histostudy.geometry import check_rigid
from histostudy.transducer import TransducerModel

from ..carm import View
from ._settings import check_n_splats, check_photons_per_pixel, check_splat_sigma_mm

if TYPE_CHECKING:  # torch is imported where a frame is rendered on it, not with the package
    import torch

__all__ = ["TorchSplatter", "poisson_noise_torch"]

#: Splat copies drawn at once: bounds the device memory (~0.4 GB) whatever the model size.
_COPIES_PER_CHUNK = 1 << 24

#: Counts of 0 become this before the log, as in the numpy reference.
_ZERO_COUNT_CLAMP = 0.5


def _torch():
    import torch  # histostudy.imaging imports without torch; a torch render alone pays its import

    return torch


class TorchSplatter:
    """A transducer model's splat renderer on one torch device.

    Args:
        model: the transducer that makes the image (e.g. the 0.125 mm physical model).
        device: a torch device (``"cuda"``, ``"cuda:0"``, ``"cpu"``).
        n_splats, splat_sigma_mm: the splatting (paper: 16 copies, 0.5 mm).
    """

    def __init__(self, model: TransducerModel, device="cuda", *, n_splats: int = 16, splat_sigma_mm: float = 0.5):
        if not isinstance(model, TransducerModel):
            raise TypeError(f"model must be a histostudy.transducer.TransducerModel, got {type(model).__name__}")
        torch = _torch()
        if torch.device(device).type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"device {device!r} asked for, but torch sees no CUDA device")
        self.device = self.device_of(device)
        self.model = model
        self.n_splats = check_n_splats(n_splats)
        self.splat_sigma_mm = check_splat_sigma_mm(splat_sigma_mm)
        points, weights = model.all_points()[0], model.all_weights()
        keep = weights > 0
        self._points = torch.as_tensor(points[keep], dtype=torch.float64, device=self.device)
        self._weights = torch.as_tensor(weights[keep], dtype=torch.float64, device=self.device)

    @staticmethod
    def device_of(device) -> torch.device:
        """``device`` as the ``torch.device`` a splatter made with it holds (``"cuda"`` -> ``cuda:0``)."""
        torch = _torch()
        device = torch.device(device)
        if device.type == "cuda" and device.index is None:
            return torch.device("cuda", torch.cuda.current_device())
        return device

    def line_integrals(self, T_carm_transducer: Sequence, views: Sequence[View], seeds: Sequence[int]) -> torch.Tensor:
        """``(B, rows, cols)`` float32 line integrals on the device, frame ``b`` at pose ``T[b]`` in ``views[b]``.

        ``T_carm_transducer`` is ``B`` 4x4 rigid poses (transducer -> C-arm, mm); the views must share
        one detector shape; ``seeds[b]`` (an integer in ``[0, 2**63)``) seeds frame ``b``'s jitter.
        """
        poses = [check_rigid(T, f"T_carm_transducer[{b}]") for b, T in enumerate(T_carm_transducer)]
        views = list(views)
        seeds = [int(s) for s in seeds]
        if not (len(poses) == len(views) == len(seeds)) or not poses:
            raise ValueError(f"T_carm_transducer, views and seeds must be as long and non-empty, got "
                             f"{len(poses)}, {len(views)} and {len(seeds)}")
        shapes = {tuple(v.shape) for v in views}
        if len(shapes) != 1:
            raise ValueError(f"views must share one detector shape, got {sorted(shapes)}")
        if any(not 0 <= s < 2**63 for s in seeds):
            raise ValueError(f"seeds must be integers in [0, 2**63), got {seeds}")
        rows, cols = shapes.pop()
        torch = _torch()
        out = torch.empty((len(poses), rows, cols), dtype=torch.float32, device=self.device)
        for b, (T, view, seed) in enumerate(zip(poses, views, seeds)):
            out[b] = self._one(T, view, seed).view(rows, cols)
        return out

    def _one(self, T: np.ndarray, view: View, seed: int) -> torch.Tensor:
        torch = _torch()
        rows, cols = view.shape
        dev = self.device
        R = torch.tensor(T[:3, :3], device=dev)
        P = torch.tensor(view.P, device=dev)
        world = self._points @ R.T + torch.tensor(T[:3, 3], device=dev)
        uvw = world @ P[:, :3].T + P[:, 3]
        in_front = uvw[:, 2] > 0
        world, uvw = world[in_front], uvw[in_front]
        distance = torch.linalg.vector_norm(world - torch.tensor(view.source_mm, device=dev), dim=1)
        footprint = uvw[:, 2].abs() ** 3 / (abs(float(np.linalg.det(view.P[:, :3]))) * distance)
        values = self._weights[in_front] / (self.n_splats * footprint)

        M = P[:, :3].float()
        base_all = uvw.float()
        n = self.n_splats
        generator = torch.Generator(device=dev).manual_seed(seed)
        image = torch.zeros(rows * cols, dtype=torch.float64, device=dev)
        chunk = max(1, _COPIES_PER_CHUNK // n)
        for start in range(0, len(values), chunk):
            base = base_all[start:start + chunk]
            if self.splat_sigma_mm > 0:
                offsets = torch.randn((len(base) * n, 3), generator=generator, device=dev)
                offsets *= self.splat_sigma_mm
                h = torch.addmm(base.repeat_interleave(n, dim=0), offsets, M.T)
            else:
                h = base.repeat_interleave(n, dim=0)
            w = h[:, 2]
            col = (h[:, 0] / w).add_(0.5)
            row = (h[:, 1] / w).add_(0.5)
            ok = (w > 0) & (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
            flat = row[ok].long() * cols + col[ok].long()
            image.index_add_(0, flat, values[start:start + chunk].repeat_interleave(n)[ok])
        return image.float()


def poisson_noise_torch(line_integrals: torch.Tensor, photons_per_pixel: float, seed: int) -> torch.Tensor:
    """Quantum noise on the device: ``counts ~ Poisson(N0 exp(-p))`` (§II-B.2).

    The numpy reference's model (:func:`~histostudy.imaging.render.add_poisson_noise`), drawn by a
    ``torch.Generator`` seeded with ``seed`` on the tensor's device.

    Args:
        line_integrals: tensor of line integrals (any shape), finite.
        photons_per_pixel: ``N0``, the unattenuated photons per pixel, finite and > 0.
        seed: the generator's seed.

    Returns:
        ``-log(max(counts, 0.5) / N0)`` as a float32 tensor on the same device.

    Raises:
        TypeError: ``line_integrals`` is not a ``torch.Tensor``.
        ValueError: it is not finite, or ``photons_per_pixel`` is out of range.
    """
    torch = _torch()
    if not isinstance(line_integrals, torch.Tensor):
        raise TypeError(f"line_integrals must be a torch.Tensor, got {type(line_integrals).__name__}")
    if not bool(torch.isfinite(line_integrals).all()):
        raise ValueError("line_integrals must be finite; found NaN or inf")
    n0 = check_photons_per_pixel(photons_per_pixel, allow_none=False)
    generator = torch.Generator(device=line_integrals.device).manual_seed(int(seed))
    rate = n0 * torch.exp(-line_integrals.double())
    counts = torch.poisson(rate, generator=generator).clamp_(min=_ZERO_COUNT_CLAMP)
    return (-torch.log(counts / n0)).float()

