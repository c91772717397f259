"""The one way to run the U-Net of §II-B.2: :class:`UNetRunner`, whole frames or regions, at a precision.

The paths, their tolerances against the reference and the tests that check them: docs/inference.md.
"""

from __future__ import annotations

import collections
import copy
import os
import threading

import numpy as np

from histostudy.core import stage
from histostudy.imaging import Frame

from ..nets.unet import max_pool_2x2
from ._fused_conv import fuse_conv_relu
from ._head_argmax import head_argmax

__all__ = ["PRECISIONS", "UNetRunner", "native_bfloat16"]

#: What a :class:`UNetRunner` computes in: ``"reference"`` (the checkpoint's float32 network as
#: trained, eagerly), ``"auto"`` (``"bfloat16"`` where :func:`native_bfloat16`, else ``"float32"``),
#: ``"float32"``, ``"bfloat16"`` or ``"int8"`` (the inference network: docs/inference.md).
PRECISIONS = ("reference", "auto", "float32", "bfloat16", "int8")

#: How many (frame, box) features a runner keeps for a second reading of the same region.
_RECENT_FEATURES = 4

#: oneDNN instruction-set levels (``ONEDNN_MAX_CPU_ISA``) at which its convolutions have native
#: bfloat16 kernels; below them torch's bfloat16 convolution is emulated or refused.
_ONEDNN_BFLOAT16_ISAS = frozenset({"AVX2_VNNI_2", "AVX512_CORE_BF16", "AVX512_CORE_FP16", "AVX512_CORE_AMX",
                                   "AVX512_CORE_AMX_FP16", "AVX10_1_512", "AVX10_1_512_AMX",
                                   "AVX10_1_512_AMX_FP16", "AVX10_2_512", "AVX10_2_512_AMX_2", "ALL", "DEFAULT"})


def native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 natively (AVX512-BF16 or AMX tiles) and torch may use it.

    A restriction of the libraries to a lower instruction set
    (:data:`histostudy.core.machine.ISA_RESTRICTION_ENV`: ``ATEN_CPU_CAPABILITY`` below avx512,
    ``ONEDNN_MAX_CPU_ISA`` below AVX512_CORE_BF16) counts as the lower CPU.

    Returns:
        True where ``precision="auto"`` runs bfloat16, False where it runs float32.
    """
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


def _fold_batch_norms(network):
    """A copy of a :class:`~histostudy.learning.nets.unet.UNet` (eval mode) with every
    ``Conv2d -> BatchNorm2d`` pair of its blocks folded into one convolution."""
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
    aligned, ``align_corners=False``): the two input indices it blends and the weight of the second."""
    src = np.maximum((np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5, 0.0)
    lo = np.minimum(np.floor(src).astype(np.intp), n_in - 1)
    hi = np.minimum(lo + 1, n_in - 1)
    return lo, hi, (src - lo).astype(np.float32)


def _channel_argmax(logits) -> np.ndarray:
    """``uint8`` arg-max over the first axis of a ``(classes, rows, cols)`` torch tensor, the first
    class on ties (as ``Tensor.argmax``): a running maximum over the classes, since torch reduces a
    leading axis of a contiguous tensor with strided loads, far slower on a whole frame."""
    import torch

    best = logits[0].clone()
    labels = torch.zeros(logits.shape[1:], dtype=torch.uint8)
    for k in range(1, logits.shape[0]):
        labels[logits[k] > best] = k
        torch.maximum(best, logits[k], out=best)
    return labels.numpy()


def _upsampled_argmax(logits: np.ndarray, labels: np.ndarray, n_rows: int, n_cols: int) -> np.ndarray:
    """The arg-max of ``logits`` (``(classes, rows, cols)``) resized bilinearly to ``n_rows x n_cols``,
    given their arg-max ``labels``: an output pixel whose four source pixels share a label takes it (a
    convex blend of logits one class leads is led by it); only the others blend their logits."""
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


class UNetRunner:
    """The U-Net of §II-B.2 run on frames: a :class:`~histostudy.learning.segment.Segmenter` of whole
    frames (:meth:`segment`) and the labels of a region at the network's grid (:meth:`segment_region`).

    ``precision="reference"`` runs the checkpoint's network as trained (eager torch, NCHW float32,
    the logits upsampled by :func:`torch.nn.functional.interpolate`): the labels the study reports.
    The other precisions run the inference network, built once here from a copy: batch norms folded,
    channels-last, each ``Conv2d -> ReLU`` in one oneDNN call, the 1x1 head and the arg-max in one
    pass, the logits upsampled along the label edges only (docs/inference.md has the paths and their
    tolerances).

    Args:
        network: the U-Net (:class:`~histostudy.learning.nets.unet.UNet`, eval mode; it is not
            modified). :meth:`segment` at ``"reference"`` takes any module mapping
            ``(1, 1, rows, cols)`` to ``(1, classes, rows, cols)`` logits; the rest needs a U-Net.
        precision: one of :data:`PRECISIONS` (default ``"reference"``); ``"auto"`` is resolved here.
        test_time_flips: ``"reference"`` only: the logits are the mean of the network's on the image
            and on its three mirror images, each flipped back (four passes; the labels mirror as the
            frame does).
        scale: the network's input scale (network pixels per frame pixel; the checkpoint's
            ``input_scale``, 0.5 for the shipped U-Net).
        manifest: the checkpoint's manifest (:mod:`histostudy.learning.checkpoints`), None for a
            network without one.
        int8_calibration: for ``"int8"``, the calibration
            (:func:`~histostudy.learning.inference.calibrate_int8`); None: the checkpoint's stored one.

    Attributes:
        precision: the precision run (``"auto"`` resolved).
        stride_px: frame pixels per network-input pixel (``1 / scale``); box corners are multiples of it.
        network_stride_px: frame pixels per cell of the U-Net's coarsest level (``pad_multiple / scale``;
            None for a ``"reference"`` network without ``pad_multiple``).
        n_fused_layers: the ``Conv2d -> ReLU`` pairs run as one call (0 for ``"reference"`` and where
            this torch cannot fuse them).
        uses_rng: False: the labels depend on the frame alone (:class:`~histostudy.learning.segment.Segmenter`).

    Raises:
        TypeError: ``test_time_flips`` is not a bool.
        ValueError: ``precision`` is not one of :data:`PRECISIONS`; ``test_time_flips`` with another
            precision than ``"reference"``; ``scale`` not finite and > 0;
            ``"int8"`` without a calibration of this checkpoint or without torch's int8 kernels.
    """

    #: The labels depend on the frame alone: a caller may segment a frame once for several estimates.
    uses_rng = False

    def __init__(self, network, precision: str = "reference", test_time_flips: bool = False, *,
                 scale: float = 0.5, manifest: dict | None = None, int8_calibration: dict | None = None):
        import torch

        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        if not isinstance(test_time_flips, bool):
            raise TypeError(f"test_time_flips must be True or False, got {test_time_flips!r}")
        if test_time_flips and precision != "reference":
            raise ValueError(f"test_time_flips runs with precision 'reference' only, got precision {precision!r}")
        scale = float(scale)
        if not (np.isfinite(scale) and scale > 0.0):
            raise ValueError(f"scale must be a finite number > 0 (network pixels per frame pixel), got {scale!r}")
        if precision == "auto":
            precision = "bfloat16" if native_bfloat16() else "float32"
        self.network, self.scale, self.manifest = network, scale, manifest
        self.precision, self.test_time_flips = precision, test_time_flips
        self.stride_px = int(round(1.0 / scale))
        pad_multiple = getattr(network, "pad_multiple", None)
        self.network_stride_px = None if pad_multiple is None else self.stride_px * int(pad_multiple)
        self.n_fused_layers = 0
        # The features of the last few (frame, box) pairs: a tracker's second warm attempt reads the
        # same regions of the same frames at a finer label grid, and needs no second forward pass.
        self._recent: collections.OrderedDict = collections.OrderedDict()
        self._recent_lock = threading.Lock()
        self._head_weights = self._int8 = self._int8_calibration = None
        self._head: torch.nn.Module | None
        if precision == "reference":
            self._dtype, self._net, self._head = torch.float32, network, getattr(network, "head", None)
            return
        self._dtype = torch.bfloat16 if precision == "bfloat16" else torch.float32
        net = _fold_batch_norms(network)
        # The head stays float32: its logits decide the arg-max, and bfloat16 would turn near-ties into ties.
        self._head = copy.deepcopy(net.head).float()
        if isinstance(self._head, torch.nn.Conv2d) and self._head.kernel_size == (1, 1) and self._head.bias is not None:
            self._head_weights = (self._head.weight.detach()[:, :, 0, 0].numpy().copy(),
                                  self._head.bias.detach().numpy().copy())
        self._net = net.to(memory_format=torch.channels_last).to(self._dtype)
        self._net, self.n_fused_layers = fuse_conv_relu(self._net)
        if precision == "int8":
            from ._int8 import Int8Features, int8_calibration_path, load_int8_calibration

            calibration = load_int8_calibration(self) if int8_calibration is None else int8_calibration
            if calibration is None:
                raise ValueError(f"precision 'int8' needs the calibration of this checkpoint: none at "
                                 f"{str(int8_calibration_path(self))!r} (histostudy calibrate-int8), and "
                                 f"int8_calibration is None")
            self._int8, self._int8_calibration = Int8Features(self, calibration), calibration

    def __reduce__(self):
        # A runner travels to sweep workers and into the sweep cache's key: it is rebuilt from what
        # made it, since its fused layers do not pickle and its recent features are this process's.
        return (_rebuilt_runner, (self.network, self.precision, self.test_time_flips, self.scale, self.manifest,
                                  self._int8_calibration))

    @classmethod
    def load(cls, path, *, precision: str = "reference", test_time_flips: bool = False) -> UNetRunner:
        """A runner of a U-Net checkpoint (its hash and configuration checked).

        Args:
            path: the checkpoint's ``.safetensors`` (its manifest beside it).
            precision: one of :data:`PRECISIONS`.
            test_time_flips: as the constructor's.

        Returns:
            The runner, at the checkpoint's ``input_scale`` (0.5 where the manifest has none).

        Raises:
            ValueError: the checkpoint cannot be loaded (missing, hash or configuration wrong) or
                holds no U-Net of the six :class:`~histostudy.transducer.Feature` classes.
        """
        from histostudy.transducer import Feature

        from ..checkpoints import load_network

        net, manifest = load_network(path)
        config = manifest["config"]  # the network's, as load_network built it
        if config.get("arch") != "unet" or config.get("n_classes") != len(Feature):
            raise ValueError(f"checkpoint {str(path)!r} holds {config}, expected a U-Net with "
                             f"{len(Feature)} classes")
        return cls(net, precision, test_time_flips, scale=float(manifest.get("input_scale", 0.5)), manifest=manifest)

    def with_precision(self, precision: str) -> UNetRunner:
        """The same network, scale and manifest at another precision (the network is shared).

        Args:
            precision: one of :data:`PRECISIONS`; ``"int8"`` reads the checkpoint's stored calibration.

        Returns:
            A new :class:`UNetRunner` (no test-time flips).

        Raises:
            ValueError: as the constructor's.
        """
        return UNetRunner(self.network, precision, scale=self.scale, manifest=self.manifest)

    @stage("segment")
    def segment(self, frame: Frame, rng: np.random.Generator | None = None) -> np.ndarray:
        """The labels of the whole frame at its full resolution: the arg-max of the logits upsampled
        bilinearly (pixel centres aligned) from the network's grid.

        Args:
            frame: the frame (its line-integral image is standardised and downscaled by ``scale``).
            rng: accepted for the :class:`~histostudy.learning.segment.Segmenter` protocol; unused.

        Returns:
            ``uint8 (rows, cols)`` :class:`~histostudy.transducer.Feature` values, the frame's shape.

        Raises:
            TypeError: ``frame`` is not a :class:`~histostudy.imaging.frame.Frame`.
            ValueError: the frame's shape does not fit ``scale`` (``"reference"``: cannot be
                downscaled; the others: not divisible by ``1 / scale``).
        """

        if not isinstance(frame, Frame):
            raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
        if self.precision == "reference":
            return self._reference_labels(frame)
        rows, cols = frame.shape
        k = self.stride_px
        if rows % k or cols % k:
            raise ValueError(f"frame of view {frame.view.name!r} with shape {frame.shape} cannot be segmented at "
                             f"scale {self.scale}: its shape is not divisible by 1/scale = {k}")
        logits = self._logits(frame, (0, rows, 0, cols))
        labels = _channel_argmax(logits)
        if k == 1:
            return labels
        return _upsampled_argmax(logits.numpy(), labels, rows, cols)

    @stage("segment")
    def segment_region(self, frame: Frame, box, upsample: int = 1) -> np.ndarray:
        """The labels of ``box`` of ``frame`` at ``upsample`` times the network's resolution.

        The network runs on the box of its input (standardised over the whole frame, then cut, padded
        as the U-Net pads). The labels lie on the grid of ``frame.view.scaled(scale * upsample)`` cut
        to the box; above ``upsample=1`` the logits are upsampled bilinearly (pixel centres aligned,
        edge pixels clamped to the box's) along the label edges. The features of the last few
        (frame, box) pairs are kept: a box read again (at another ``upsample``) runs no second
        forward pass, as long as the frame's image is not changed in place.

        Args:
            frame: the frame.
            box: ``(row0, row1, col0, col1)`` in frame pixels, half-open, all four multiples of
                :attr:`stride_px`.
            upsample: label pixels per network pixel, an integer in ``[1, stride_px]``.

        Returns:
            ``uint8`` labels of shape ``((row1 - row0) * scale * upsample, (col1 - col0) * scale * upsample)``.

        Raises:
            TypeError: ``frame`` is not a :class:`~histostudy.imaging.frame.Frame`.
            ValueError: ``box`` is not 4 integers inside the frame on multiples of :attr:`stride_px`,
                or ``upsample`` is out of range; ``test_time_flips`` is set (whole frames only).
        """

        if not isinstance(frame, Frame):
            raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
        if self.test_time_flips:
            raise ValueError("segment_region runs without test-time flips: use segment, or a runner without them")
        if (isinstance(upsample, bool) or not isinstance(upsample, (int, np.integer))
                or not 1 <= upsample <= self.stride_px):
            raise ValueError(f"upsample must be an integer in [1, {self.stride_px}] (labels at most at the frame's "
                             f"resolution), got {upsample!r}")
        if upsample == 1:
            return self._labels(frame, box)
        logits = self._logits(frame, box)
        labels = _channel_argmax(logits)
        return _upsampled_argmax(logits.numpy(), labels, labels.shape[0] * int(upsample),
                                 labels.shape[1] * int(upsample))

    # --- the reference ---------------------------------------------------------------------------

    def _input(self, frame: Frame) -> np.ndarray:
        from ..preprocess import prepare_image

        try:
            return prepare_image(frame.image, self.scale)
        except ValueError as exc:
            raise ValueError(f"frame of view {frame.view.name!r} with shape {frame.image.shape} cannot be "
                             f"segmented at scale {self.scale}: {exc}") from None

    def _reference_labels(self, frame: Frame) -> np.ndarray:
        """The checkpoint's network as trained on the whole frame (with test-time flips if set), the
        logits upsampled by torch to the frame's shape, then the arg-max."""
        import torch
        from torch.nn import functional as F

        pixels = self._input(frame)
        self.network.eval()
        with torch.no_grad():
            x = torch.from_numpy(pixels)[None, None]
            logits = self.network(x)
            if self.test_time_flips:
                for dims in ((-1,), (-2,), (-2, -1)):
                    logits = logits + torch.flip(self.network(torch.flip(x, dims)), dims)
                logits = logits / 4.0
            if logits.shape[-2:] != frame.image.shape:
                logits = F.interpolate(logits, size=frame.image.shape, mode="bilinear", align_corners=False)
            return _channel_argmax(logits[0])

    # --- regions -----------------------------------------------------------------------------------

    def _features(self, frame: Frame, box):
        """The last decoder block's output on ``box`` at the network's resolution, before the head (a
        ``(1, channels, rows', cols')`` tensor, padded as the U-Net pads), and the box's ``(rows, cols)``
        at the network's resolution."""
        import torch

        r0, r1, c0, c1 = self._check_box(box, frame.shape)
        key = (id(frame), r0, r1, c0, c1)
        with self._recent_lock:
            hit = self._recent.get(key)
        # the frame object and its image array held in the entry: the same id is the same frame
        if hit is not None and hit[0] is frame and hit[1] is frame.image:
            return hit[2], hit[3]
        x = self._input(frame)
        k = self.stride_px
        x = np.ascontiguousarray(x[r0 // k:r1 // k, c0 // k:c1 // k])
        with torch.no_grad():
            rows, cols = x.shape
            t = self.network.pad(torch.from_numpy(x)[None, None])
            if self.precision != "reference":
                t = t.contiguous(memory_format=torch.channels_last).to(self._dtype)
            features = self._network_features(t)
        with self._recent_lock:
            self._recent[key] = (frame, frame.image, features, (rows, cols))
            while len(self._recent) > _RECENT_FEATURES:
                self._recent.popitem(last=False)
        return features, (rows, cols)

    def _network_features(self, x):
        """The last decoder block's output of a padded network input ``x``: the int8 network's, the
        inference network's, or (``"reference"``) the checkpoint's."""
        if self._int8 is not None:
            return self._int8.features(x)
        if self.precision == "reference":
            self.network.eval()
            return self.network.features(x)
        return self._net.features(x, pool=max_pool_2x2)

    def _logits(self, frame: Frame, box):
        """float32 logits ``(classes, rows, cols)`` of ``box`` at the network's resolution (a torch
        tensor; channels-last strides on the inference network, whose arg-max then reads contiguous memory)."""
        import torch

        features, (rows, cols) = self._features(frame, box)
        with torch.no_grad():
            logits = self._head_module()(features.float())
        return logits[0, :, :rows, :cols]

    def _labels(self, frame: Frame, box) -> np.ndarray:
        """``uint8`` arg-max labels of ``box`` at the network's resolution: the head and the arg-max in
        one pass (:func:`~histostudy.learning.inference._head_argmax.head_argmax`) where the inference
        network's head is a 1x1 convolution, else the arg-max of :meth:`_logits`."""
        import torch

        if self._head_weights is None:
            return _channel_argmax(self._logits(frame, box))
        features, (rows, cols) = self._features(frame, box)
        # channels-last memory is (1, rows', cols', channels); bfloat16 goes in as its bits
        hwc = features[0, :, :rows, :cols].permute(1, 2, 0)
        hwc = hwc.view(torch.uint16) if hwc.dtype == torch.bfloat16 else hwc.float()
        return head_argmax(hwc.contiguous().numpy(), *self._head_weights)

    def _forward(self, x):
        """The network's layers and the float32 head on a padded network input ``x`` (of the runner's
        dtype and memory format): float32 logits."""
        return self._head_module()(self._network_features(x).float())

    def _head_module(self):
        """The network's 1x1 head (float32); ``ValueError`` for a network that has none."""
        if self._head is None:
            raise ValueError(f"network {type(self.network).__name__} has no 'head': a U-Net's labels come from it")
        return self._head

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
        flips = ", test_time_flips=True" if self.test_time_flips else ""
        return f"UNetRunner(precision={self.precision!r}, scale={self.scale}{flips})"


def _rebuilt_runner(network, precision, test_time_flips, scale, manifest, int8_calibration) -> UNetRunner:
    return UNetRunner(network, precision, test_time_flips, scale=scale, manifest=manifest,
                      int8_calibration=int8_calibration)
