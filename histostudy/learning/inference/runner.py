"""The U-Net of §II-B.2 made fast for tracking on CPU: :class:`FastUNet`, labels of a region at the
network's resolution.

:class:`~.segment.UNetSegmenter` (the torch checkpoint, the source of truth) segments a whole frame
and upsamples the six logit channels bilinearly to the frame's full resolution before the
arg-max. For tracking (``histostudy.pose.Tracker(fast=True)``, docs/tracking.md) most of that work
is waste: the logits carry no detail finer than the network's input grid, and the pose only needs
the region where the transducer projects. :class:`FastUNet` therefore

- folds each batch normalisation into the convolution before it (inference only: the same
  function, one pass over memory less per layer) and keeps activations channels-last, which the
  CPU convolutions run faster than NCHW (docs/tracking-alternatives.md, "The network's inference path");
- runs each convolution and the ReLU after it as one oneDNN call (:mod:`.fused_conv`: within
  float32 rounding of the eager pair, one pass over the activations less; about a fifth of the
  network's time), and pools as the maximum of four strided quarters
  (:func:`~.nets.unet.max_pool_2x2`: the same values, faster than ``max_pool2d`` on
  channels-last activations);
- on a CPU with native bfloat16 arithmetic (AVX512-BF16 or AMX), runs the convolutions in
  bfloat16 and the final 1x1 convolution in float32 (``precision="auto"``): faster again, with
  99.9 % of the labels unchanged (tests/learning/test_fast_segment.py checks the agreement with
  the checkpoint run eagerly in float32);
- runs the network on a box of the input (the same :func:`~.preprocess.prepare_image` transform,
  standardised over the whole frame as in training, then cropped), padded as
  :class:`~.nets.unet.UNet` pads;
- computes the 1x1 head and the arg-max in one pass over the features (:mod:`.head_argmax`), so
  the six logit channels of a region are never written out;
- takes the arg-max at the network's resolution: the labels live on the grid of
  ``view.scaled(scale)`` restricted to the box (pixel centres as in
  :meth:`~histostudy.imaging.carm.View.scaled`), not on the frame's.

:meth:`FastUNet.segment` is the same network as a :class:`~.segment.Segmenter` of whole frames at
their full resolution (the tracker's from-scratch estimates): the arg-max of the bilinearly
upsampled logits equals the arg-max at the network's resolution wherever the four logit vectors
the interpolation blends share their arg-max (a convex combination keeps a common maximum), so
only the pixels where they differ, along the label edges, are interpolated; so does
:meth:`FastUNet.segment_region` above the network's resolution (a tracker's second warm attempt,
which reads the box's features kept from its first).

Boxes are ``(row0, row1, col0, col1)`` in full-frame pixels, half-open, with all four multiples
of :attr:`FastUNet.stride_px` (one network-input pixel for every ``1 / scale`` frame pixels,
``histostudy.pose.tracking._roi`` aligns them to a whole U-Net stride). Measured alternatives that
did not pay off (TorchScript freezing, ``torch.compile``, batching the two views, int8 static
quantisation, ONNX Runtime, the shipped network on a quarter-scale input) are in
docs/tracking-alternatives.md,
with the U-Net trained at 0.25 for tracking (``data/models/unet_tracking``).
"""

from __future__ import annotations

import collections
import copy
import threading

import numpy as np

from histostudy.imaging import Frame

from .fused_conv import fuse_conv_relu
from .head_argmax import head_argmax
from .nets import max_pool_2x2
from .segment import UNetSegmenter

__all__ = ["FAST_UNET_PRECISIONS", "FastUNet", "auto_precision", "native_bfloat16"]

#: What :class:`FastUNet` computes in: ``"auto"`` (:func:`auto_precision`), ``"float32"``,
#: ``"bfloat16"`` or ``"int8"`` (:mod:`.int8_unet`).
FAST_UNET_PRECISIONS = ("auto", "float32", "bfloat16", "int8")

#: How many (frame, box) features a FastUNet keeps for a second reading of the same region.
_RECENT_FEATURES = 4


#: oneDNN instruction-set levels (``ONEDNN_MAX_CPU_ISA``) at which its convolutions have native
#: bfloat16 kernels; below them (AVX2, AVX512_CORE without BF16 ...) torch's bfloat16 convolution
#: is emulated or refused.
_ONEDNN_BFLOAT16_ISAS = frozenset({"AVX2_VNNI_2", "AVX512_CORE_BF16", "AVX512_CORE_FP16", "AVX512_CORE_AMX",
                                   "AVX512_CORE_AMX_FP16", "AVX10_1_512", "AVX10_1_512_AMX",
                                   "AVX10_1_512_AMX_FP16", "AVX10_2_512", "AVX10_2_512_AMX_2", "ALL", "DEFAULT"})


def native_bfloat16() -> bool:
    """True when this CPU computes bfloat16 natively (AVX512-BF16 or AMX tiles) and torch may use
    it, where bfloat16 convolutions run faster than float32 ones; elsewhere they are emulated and
    slower. A restriction of the libraries to a lower instruction set
    (:data:`histostudy.core.machine.ISA_RESTRICTION_ENV`: ``ATEN_CPU_CAPABILITY`` below avx512,
    ``ONEDNN_MAX_CPU_ISA`` below AVX512_CORE_BF16) counts as the lower CPU."""
    import os

    import torch

    onednn_isa = os.environ.get("ONEDNN_MAX_CPU_ISA") or os.environ.get("DNNL_MAX_CPU_ISA")
    if onednn_isa and onednn_isa.strip().upper() not in _ONEDNN_BFLOAT16_ISAS:
        return False
    try:
        if not torch.backends.cpu.get_cpu_capability().startswith("AVX512"):
            return False
        return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
    except (AttributeError, RuntimeError):
        return False


def auto_precision(segmenter: UNetSegmenter) -> str:
    """What ``precision="auto"`` runs ``segmenter`` in here: ``"bfloat16"`` on a CPU with native
    bfloat16 (:func:`native_bfloat16`), else ``"float32"``. ``"int8"`` (:mod:`.int8_unet`) is
    asked for by name: on the tracker's cines it moved single poses by up to 0.2 mm against
    float32's, past the 0.1 mm the fast path keeps to the full-frame path (docs/tracking.md)."""
    if not isinstance(segmenter, UNetSegmenter):
        raise TypeError(f"segmenter must be a histostudy.learning.UNetSegmenter, got {type(segmenter).__name__}")
    return "bfloat16" if native_bfloat16() else "float32"


def _fold_batch_norms(network):
    """A copy of a :class:`~.nets.unet.UNet` (eval mode) with every ``Conv2d -> BatchNorm2d`` pair of
    its blocks folded into one convolution."""
    from torch import nn
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    net = copy.deepcopy(network).eval()
    if getattr(net, "stem", None) is not None:
        conv, norm, relu = net.stem
        net.stem = nn.Sequential(fuse_conv_bn_eval(conv, norm), relu)
    for blocks in (net.down, net.dec):
        for j, block in enumerate(blocks):
            layers, folded, i = list(block), [], 0
            while i < len(layers):
                if (i + 1 < len(layers) and isinstance(layers[i], nn.Conv2d)
                        and isinstance(layers[i + 1], nn.BatchNorm2d)):
                    folded.append(fuse_conv_bn_eval(layers[i], layers[i + 1]))
                    i += 2
                else:
                    folded.append(layers[i])
                    i += 1
            blocks[j] = nn.Sequential(*folded)
    return net


def _bilinear_support(n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per output index of a bilinear resize from ``n_in`` to ``n_out`` samples (pixel centres
    aligned, ``align_corners=False`` as :meth:`UNetSegmenter.segment` resizes): the two input
    indices it blends and the weight of the second."""
    src = np.maximum((np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5, 0.0)
    lo = np.minimum(np.floor(src).astype(np.intp), n_in - 1)
    hi = np.minimum(lo + 1, n_in - 1)
    return lo, hi, (src - lo).astype(np.float32)


def _upsampled_argmax(logits: np.ndarray, labels: np.ndarray, n_rows: int, n_cols: int) -> np.ndarray:
    """The arg-max of ``logits`` (``(classes, rows, cols)``) resized bilinearly to ``n_rows x n_cols``
    (:func:`_bilinear_support`), given their arg-max ``labels`` at their own size: an output pixel
    whose four source pixels share a label takes it (a convex blend of logits that one class leads
    is led by it); only the others blend their logits."""
    (y0, y1, wy), (x0, x1, wx) = _bilinear_support(n_rows, labels.shape[0]), _bilinear_support(n_cols, labels.shape[1])
    top, bottom = labels[y0], labels[y1]
    out = np.take(top, x0, axis=1)
    mixed = out != np.take(top, x1, axis=1)
    mixed |= out != np.take(bottom, x0, axis=1)
    mixed |= out != np.take(bottom, x1, axis=1)
    v, u = np.nonzero(mixed)
    if len(v):
        a, b, c, d = (logits[:, y0[v], x0[u]], logits[:, y0[v], x1[u]], logits[:, y1[v], x0[u]],
                      logits[:, y1[v], x1[u]])
        blended = (1 - wy[v]) * ((1 - wx[u]) * a + wx[u] * b) + wy[v] * ((1 - wx[u]) * c + wx[u] * d)
        out[v, u] = blended.argmax(axis=0)
    return out


class FastUNet:
    """Fast CPU inference of a :class:`~.segment.UNetSegmenter`'s network on a region of a frame.

    Args:
        segmenter: the :class:`UNetSegmenter` whose checkpoint (weights, input scale) this runs;
            it is not modified (its network is copied and folded).
        precision: one of :data:`FAST_UNET_PRECISIONS`: ``"auto"`` (default) resolves by
            :func:`auto_precision` (bfloat16 on a CPU with native bfloat16, else float32);
            ``"int8"``: :class:`~.int8_unet.Int8UNet` (the checkpoint's stored calibration).
        int8_calibration: for ``"int8"``, the calibration (:func:`~.int8_unet.calibrate_int8`);
            None: the checkpoint's stored one (a ValueError where there is none).

    Attributes:
        segmenter: the reference segmenter (the torch checkpoint as loaded).
        scale: the network's input scale (the checkpoint's ``input_scale``, 0.5 for the shipped
            U-Net): labels have ``scale`` times the frame's rows and columns.
        stride_px: frame pixels per network-input pixel (``1 / scale``); box corners are multiples of it.
        network_stride_px: frame pixels per cell of the U-Net's coarsest level (``pad_multiple / scale``,
            :attr:`~.nets.unet.UNet.pad_multiple`).
        precision: ``"float32"``, ``"bfloat16"`` or ``"int8"`` (``"auto"`` resolved).
        n_fused_layers: the network's ``Conv2d -> ReLU`` pairs run as one call
            (:func:`~.fused_conv.fuse_conv_relu`; 0 where this torch cannot fuse them).
    """

    def __init__(self, segmenter: UNetSegmenter, *, precision: str = "auto", int8_calibration: dict | None = None):
        import torch

        if not isinstance(segmenter, UNetSegmenter):
            raise TypeError(f"segmenter must be a histostudy.learning.UNetSegmenter, got {type(segmenter).__name__}")
        if precision not in FAST_UNET_PRECISIONS:
            raise ValueError(f"precision must be one of {FAST_UNET_PRECISIONS}, got {precision!r}")
        if precision == "auto":
            precision = auto_precision(segmenter)
        self.segmenter = segmenter
        self.precision = precision
        self.scale = float(segmenter.scale)
        self.stride_px = int(round(1.0 / self.scale))
        self.network_stride_px = self.stride_px * int(segmenter.network.pad_multiple)
        self._dtype = torch.bfloat16 if precision == "bfloat16" else torch.float32
        net = _fold_batch_norms(segmenter.network)
        # The last 1x1 convolution stays float32: its logits decide the arg-max, and bfloat16's
        # 8-bit mantissa would turn near-ties into ties.
        self._head = copy.deepcopy(net.head).float()
        # A 1x1 head runs with the arg-max in one pass over the features (head_argmax.py).
        self._head_weights = None
        if isinstance(self._head, torch.nn.Conv2d) and self._head.kernel_size == (1, 1) and self._head.bias is not None:
            self._head_weights = (self._head.weight.detach()[:, :, 0, 0].numpy().copy(),
                                  self._head.bias.detach().numpy().copy())
        self._net = net.to(memory_format=torch.channels_last).to(self._dtype)
        # Each Conv2d -> ReLU in one oneDNN call where that keeps float32 rounding's bound (fused_conv.py).
        self._net, self.n_fused_layers = fuse_conv_relu(self._net)
        # The features of the last few (frame, box) pairs: a tracker's second warm attempt reads the
        # same regions of the same frames at a finer label grid, and needs no second forward pass.
        self._recent: collections.OrderedDict = collections.OrderedDict()
        self._recent_lock = threading.Lock()
        self._int8 = None
        if precision == "int8":
            from .int8_unet import Int8UNet, int8_calibration_path, load_int8_calibration

            calibration = load_int8_calibration(segmenter) if int8_calibration is None else int8_calibration
            if calibration is None:
                raise ValueError(f"precision 'int8' needs the calibration of this checkpoint: none at "
                                 f"{str(int8_calibration_path(segmenter))!r} (histostudy calibrate-int8), and "
                                 f"int8_calibration is None")
            self._int8 = Int8UNet(segmenter, calibration)

    def segment_region(self, frame: Frame, box, upsample: int = 1) -> np.ndarray:
        """``uint8`` labels (:class:`~histostudy.transducer.Feature` values) of ``box`` of ``frame``
        at ``upsample`` times the network's resolution: shape ``((row1 - row0) * scale * upsample,
        (col1 - col0) * scale * upsample)``, the arg-max of the logits on the grid of
        ``frame.view.scaled(scale * upsample)`` cut to the box. With ``upsample`` > 1 the logits
        are upsampled bilinearly first (pixel centres aligned, as :meth:`segment` and
        :meth:`~.segment.UNetSegmenter.segment` upsample; edge pixels clamp to the box's), which
        places the label edges between the network's pixels (a U-Net run at 0.25 labelling at 0.5);
        as in :meth:`segment`, only the pixels along the label edges are interpolated. The features
        of the last few (frame, box) pairs are kept: reading a box of a frame again (at another
        ``upsample``) runs no second forward pass, as long as the frame's image is not changed in place."""
        import torch

        if not isinstance(frame, Frame):
            raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
        if isinstance(upsample, bool) or not isinstance(upsample, (int, np.integer)) or not 1 <= upsample <= self.stride_px:
            raise ValueError(f"upsample must be an integer in [1, {self.stride_px}] (labels at most at the frame's "
                             f"resolution), got {upsample!r}")
        if upsample == 1:
            return self._labels(frame, box)
        logits = self._logits(frame, box)
        labels = logits.argmax(dim=0).to(torch.uint8).numpy()
        return _upsampled_argmax(logits.numpy(), labels, labels.shape[0] * int(upsample),
                                 labels.shape[1] * int(upsample))

    def segment(self, frame: Frame, rng: np.random.Generator | None = None) -> np.ndarray:
        """``uint8`` labels of the whole frame at its full resolution, as
        :meth:`~.segment.UNetSegmenter.segment` gives them (module docstring): a
        :class:`~.segment.Segmenter`. ``rng`` is accepted for the protocol and unused."""
        import torch

        if not isinstance(frame, Frame):
            raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
        rows, cols = frame.shape
        k = self.stride_px
        if rows % k or cols % k:
            raise ValueError(f"frame of view {frame.view.name!r} with shape {frame.shape} cannot be segmented at "
                             f"scale {self.scale}: its shape is not divisible by 1/scale = {k}")
        logits = self._logits(frame, (0, rows, 0, cols))
        labels = logits.argmax(dim=0).to(torch.uint8).numpy()
        if k == 1:
            return labels
        return _upsampled_argmax(logits.numpy(), labels, rows, cols)

    def _features(self, frame: Frame, box):
        """The last decoder block's output on ``box`` at the network's resolution, before the head: a
        ``(1, channels, rows', cols')`` tensor of the network's dtype, channels-last, padded as
        :class:`~.nets.unet.UNet` pads; and the box's ``(rows, cols)`` at the network's resolution."""
        import torch

        from .preprocess import prepare_image

        r0, r1, c0, c1 = self._check_box(box, frame.shape)
        key = (id(frame), r0, r1, c0, c1)
        with self._recent_lock:
            hit = self._recent.get(key)
        # the frame object and its image array held in the entry: the same id is the same frame
        if hit is not None and hit[0] is frame and hit[1] is frame.image:
            return hit[2], hit[3]
        try:
            x = prepare_image(frame.image, self.scale)
        except ValueError as exc:
            raise ValueError(f"frame of view {frame.view.name!r} with shape {frame.image.shape} cannot be "
                             f"segmented at scale {self.scale}: {exc}") from None
        k = self.stride_px
        x = np.ascontiguousarray(x[r0 // k:r1 // k, c0 // k:c1 // k])
        with torch.no_grad():
            rows, cols = x.shape
            t = self.segmenter.network.pad(torch.from_numpy(x)[None, None])
            x = t.contiguous(memory_format=torch.channels_last).to(self._dtype)
            features = self._network_features(x)
        with self._recent_lock:
            self._recent[key] = (frame, frame.image, features, (rows, cols))
            while len(self._recent) > _RECENT_FEATURES:
                self._recent.popitem(last=False)
        return features, (rows, cols)

    def _network_features(self, x):
        """The last decoder block's output of ``x`` (channels-last, of the network's dtype, sides
        multiples of ``pad_multiple``): the int8 network's where there is one, else the folded one's."""
        return self._int8.features(x) if self._int8 is not None else self._net.features(x, pool=max_pool_2x2)

    def _logits(self, frame: Frame, box):
        """float32 logits ``(6, rows, cols)`` (a torch tensor, channels-last strides) of ``box`` at the
        network's resolution."""
        import torch

        features, (rows, cols) = self._features(frame, box)
        with torch.no_grad():
            logits = self._head(features.float())
        # Kept channels-last (the classes innermost): the arg-max over the classes then reads
        # contiguous memory, an order of magnitude faster than making a whole frame NCHW-contiguous
        # first (docs/tracking.md, "From scratch in under a second").
        return logits[0, :, :rows, :cols]

    def _labels(self, frame: Frame, box) -> np.ndarray:
        """``uint8`` arg-max labels of ``box`` at the network's resolution: the head and the arg-max in
        one pass (:func:`~.head_argmax.head_argmax`) where the head is a 1x1 convolution, else the
        arg-max of :meth:`_logits`."""
        import torch

        if self._head_weights is None:
            return self._logits(frame, box).argmax(dim=0).to(torch.uint8).numpy()
        features, (rows, cols) = self._features(frame, box)
        # channels-last memory is (1, rows', cols', channels); bfloat16 goes in as its bits
        hwc = features[0, :, :rows, :cols].permute(1, 2, 0)
        hwc = hwc.view(torch.uint16) if hwc.dtype == torch.bfloat16 else hwc.float()
        return head_argmax(hwc.contiguous().numpy(), *self._head_weights)

    def _forward(self, x):
        """The U-Net's layers (:meth:`_network_features`, then the float32 head) on ``x`` (of the
        network's dtype), whose rows and columns are multiples of ``pad_multiple``: float32 logits."""
        return self._head(self._network_features(x).float())

    def _check_box(self, box, shape) -> tuple[int, int, int, int]:
        try:
            r0, r1, c0, c1 = (int(b) for b in box)
            if any(int(b) != b for b in box):
                raise ValueError
        except (TypeError, ValueError):
            raise ValueError(f"box must be 4 integers (row0, row1, col0, col1) in frame pixels, got {box!r}") from None
        rows, cols = shape
        k = self.stride_px
        if not (0 <= r0 < r1 <= rows and 0 <= c0 < c1 <= cols):
            raise ValueError(f"box {box!r} must lie in the frame's {shape} pixels with row0 < row1, col0 < col1")
        if any(b % k for b in (r0, r1, c0, c1)):
            raise ValueError(f"box {box!r} must have its corners on multiples of {k} frame pixels (1 / scale)")
        return r0, r1, c0, c1

    def __repr__(self) -> str:
        return f"FastUNet(scale={self.scale}, network_stride_px={self.network_stride_px}, precision={self.precision!r})"
