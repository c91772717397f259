"""The U-Net's 1x1 head and the arg-max over its classes in one pass over the features, for
:meth:`~.runner.UNetRunner.segment_region`: :func:`head_argmax` (its summation order and ties:
docs/inference.md, "Head and arg-max").
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = []


#: Pixels per block: the block's accumulators stay in the first-level cache, and the loops over its
#: pixels (no reduction across them) vectorise.
_BLOCK = 256


@numba.njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def _head_argmax(features, bfloat16_bits, weight, bias, out):
    n, n_in = features.shape
    n_classes = weight.shape[0]
    acc = np.empty(_BLOCK, np.float32)
    planes = np.empty((n_in, _BLOCK), np.float32)
    plane_bits = planes.view(np.uint32)  # bfloat16 is the upper half of a float32's bits
    best_value = np.empty(_BLOCK, np.float32)
    best = np.empty(_BLOCK, np.uint8)
    for p0 in range(0, n, _BLOCK):
        block = features[p0:min(p0 + _BLOCK, n)]
        m = block.shape[0]
        # channel planes: the loops below then read contiguous memory
        if bfloat16_bits:
            for j in range(m):
                for c in range(n_in):
                    plane_bits[c, j] = np.uint32(block[j, c]) << np.uint32(16)
        else:
            for j in range(m):
                for c in range(n_in):
                    planes[c, j] = block[j, c]
        for k in range(n_classes):
            w0 = weight[k, 0]
            plane = planes[0]
            for j in range(m):
                acc[j] = plane[j] * w0
            for c in range(1, n_in):
                wc = weight[k, c]
                plane = planes[c]
                for j in range(m):
                    acc[j] = acc[j] + plane[j] * wc
            b = bias[k]
            for j in range(m):
                value = np.float32(acc[j] + b)
                # the first of equal maxima, as torch.argmax
                take = (k == 0) | (value > best_value[j])
                best_value[j] = value if take else best_value[j]
                best[j] = np.uint8(k) if take else best[j]
        for j in range(m):
            out[p0 + j] = best[j]


def head_argmax(features: np.ndarray, weight: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """``uint8`` labels ``(rows, cols)``: per pixel the arg-max over classes ``k`` of
    ``bias[k] + sum_c weight[k, c] * features[..., c]`` (docs/inference.md, "Head and arg-max").

    Args:
        features: ``(rows, cols, n_in)``, the last decoder block's output (channels innermost, as a
            channels-last tensor's memory holds it): float32, or uint16 holding bfloat16 bits (a
            bfloat16 tensor's ``view(torch.uint16)``; widened exactly, as ``Tensor.float()`` does).
        weight: ``(n_classes, n_in)`` float32, the 1x1 convolution's weights.
        bias: ``(n_classes,)`` float32.
    """
    features = np.asarray(features)
    weight = np.ascontiguousarray(weight, dtype=np.float32)
    bias = np.ascontiguousarray(bias, dtype=np.float32)
    if features.ndim != 3 or features.dtype not in (np.float32, np.uint16):
        raise ValueError(f"features must be a (rows, cols, channels) float32 array or uint16 bfloat16 bits, got "
                         f"{features.dtype} {features.shape}")
    if weight.ndim != 2 or weight.shape[1] != features.shape[2] or bias.shape != (weight.shape[0],) \
            or not 1 <= weight.shape[0] <= 255:
        raise ValueError(f"weight must be (n_classes <= 255, {features.shape[2]}) and bias (n_classes,), got "
                         f"{weight.shape} and {bias.shape}")
    rows, cols, n_in = features.shape
    out = np.empty(rows * cols, np.uint8)
    _head_argmax(np.ascontiguousarray(features).reshape(rows * cols, n_in), features.dtype == np.uint16, weight,
                 bias, out)
    return out.reshape(rows, cols)
