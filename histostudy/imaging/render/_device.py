"""Where a frame's splatting runs (§II-B.2): the numpy reference, compiled on the CPU, or torch on a device;
the same projection, a different source of jitter (docs/imaging.md, "Splatting")."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from histostudy.transducer import FEATURE_CLASSES, TransducerModel

from ..carm import View

if TYPE_CHECKING:
    from ._torch import TorchSplatter

__all__ = ["check_device", "mark_nearest_pixels_compiled", "splat_compiled", "splat_points", "splat_torch"]

#: A splat stream's seed is one draw in [0, 2**63) from the caller's Generator.
SEED_BOUND = 2**63


def check_device(device):
    """``device`` checked: None, ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or a ``torch.device``; returns it.

    Raises ValueError naming the value for anything else, and for a CUDA device when torch sees
    none (a frame is never rendered elsewhere than asked).
    """
    if device is None:
        return None
    name = str(device) if type(device).__name__ == "device" else device
    if not isinstance(name, str) or not (name == "cpu" or name == "cuda" or
                                         (name.startswith("cuda:") and name[5:].isdigit())):
        raise ValueError(f"device must be None (numpy reference), 'cpu' (compiled) or 'cuda'/'cuda:N' "
                         f"(torch), got {device!r}")
    if name.startswith("cuda"):
        import torch  # only a CUDA render needs torch

        if not torch.cuda.is_available():
            raise ValueError(f"device {device!r} asked for, but torch sees no CUDA device")
    return name


def splat_points(model: TransducerModel, T_carm_transducer: np.ndarray, view: View,
                 n_splats: int) -> tuple[np.ndarray, np.ndarray]:
    """The points every splatting renderer projects: ``(uvw, values)``.

    ``uvw`` ``(m, 3)`` float64 are the homogeneous image coordinates (eq. 1) of the model's points
    with non-zero weight that lie in front of the source (w > 0), in enum order of the classes;
    ``values`` ``(m,)`` float64 is what one of a point's ``n_splats`` copies adds to its pixel,
    ``weight / (n_splats * footprint)`` (footprint in mm², :meth:`View.pixel_footprint_mm2`).
    The arguments are the caller's, already checked.
    """
    points, weights = model.all_points()[0], model.all_weights()
    keep = weights > 0
    world = points[keep] @ T_carm_transducer[:3, :3].T + T_carm_transducer[:3, 3]
    uvw = view.project_homogeneous(world)
    in_front = uvw[:, 2] > 0
    world, uvw, weights = world[in_front], uvw[in_front], weights[keep][in_front]
    return uvw, weights / (n_splats * view.pixel_footprint_mm2(world))


def splat_compiled(model: TransducerModel, T_carm_transducer: np.ndarray, view: View, *, seed: int, n_splats: int,
                   splat_sigma_mm: float) -> np.ndarray:
    """The ``view.shape`` float32 line integrals of ``model`` at ``T_carm_transducer``, by the compiled
    kernel (:func:`._splat_kernels.splat_into`, class by class; the arguments already checked).

    The kernel projects the points itself (from ``A = P [R t]``, the source taken into the
    transducer frame), so nothing per point is built in numpy; point ``i`` of the classes in enum
    order draws from stream ``i``.
    """
    from ._splat_kernels import N_PARTS, splat_into  # numba compiles on first use; imaging alone does not need it

    rows, cols = view.shape
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    A = view.P @ T
    source = T[:3, :3].T @ (view.source_mm - T[:3, 3])
    det_M = abs(float(np.linalg.det(view.P[:, :3])))
    M = np.ascontiguousarray(view.P[:, :3], dtype=np.float32)
    partial = np.zeros((N_PARTS, rows * cols), dtype=np.float64)
    first = 0
    for feature in FEATURE_CLASSES:
        points = np.ascontiguousarray(model.points[feature], dtype=np.float64)
        weights = np.ascontiguousarray(model.weights[feature], dtype=np.float64)
        if len(points):
            splat_into(partial, points, weights, first, A, det_M, source, M, np.float32(splat_sigma_mm),
                       int(n_splats), np.uint64(seed), rows, cols)
        first += len(points)
    return partial.sum(axis=0).reshape(rows, cols).astype(np.float32)


def splat_torch(model: TransducerModel, T_carm_transducer: np.ndarray, view: View, *, device: str, seed: int,
                n_splats: int, splat_sigma_mm: float) -> np.ndarray:
    """The ``view.shape`` float32 line integrals of one frame by torch on ``device`` (arguments checked).

    The :class:`~._torch.TorchSplatter` of the last call is kept while the model, device and
    splatting stay the same, so that a run of frames moves the model's points to the GPU once.
    """
    from ._torch import TorchSplatter  # torch only for a torch render

    global _LAST_SPLATTER
    last = _LAST_SPLATTER
    if (last is None or last.model is not model or str(last.device) != str(TorchSplatter.device_of(device))
            or last.n_splats != n_splats or last.splat_sigma_mm != splat_sigma_mm):
        _LAST_SPLATTER = last = TorchSplatter(model, device, n_splats=n_splats, splat_sigma_mm=splat_sigma_mm)
    return last.line_integrals([T_carm_transducer], [view], [seed])[0].cpu().numpy()


_LAST_SPLATTER: TorchSplatter | None = None


def mark_nearest_pixels_compiled(points: np.ndarray, T_carm_transducer: np.ndarray,
                                 view: View) -> tuple[np.ndarray, float]:
    """The flat ``(rows * cols,)`` uint8 mask of the pixels ``points`` (mm, transducer frame) land in
    at ``T_carm_transducer``, and their smallest pixel footprint in mm² (inf: none lands), by the
    compiled kernel (:func:`._splat_kernels.mark_nearest_pixels`)."""
    from ._splat_kernels import mark_nearest_pixels  # numba compiles on first use

    rows, cols = view.shape
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    mask = np.zeros(rows * cols, dtype=np.uint8)
    smallest = mark_nearest_pixels(mask, np.ascontiguousarray(points, dtype=np.float64),
                                   np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), view.P,
                                   view.source_mm, abs(float(np.linalg.det(view.P[:, :3]))), rows, cols)
    return mask, float(smallest)
