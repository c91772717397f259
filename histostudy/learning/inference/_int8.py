"""The U-Net's int8 inference network (precision ``"int8"`` of a
:class:`~histostudy.learning.inference.runner.UNetRunner`) and its calibration, stored beside the
weights with their SHA-256 (docs/inference.md, "int8").
"""

from __future__ import annotations

import contextlib
import copy
import json
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from histostudy.imaging import Frame

__all__ = ["INT8_CALIBRATION_FORMAT", "INT8_ENGINE", "Int8Features", "calibrate_int8", "int8_available",
           "int8_calibration_path", "load_int8_calibration", "save_int8_calibration"]

#: The quantised engine whose kernels the int8 network runs on (oneDNN's: AVX2, AVX-512 VNNI, AMX).
INT8_ENGINE = "onednn"

#: The format tag of a calibration file.
INT8_CALIBRATION_FORMAT = "histostudy.int8-calibration/1"


def int8_available() -> bool:
    """Whether this torch can run precision ``"int8"``.

    Returns:
        True where torch has :data:`INT8_ENGINE`'s quantised kernels (x86-64 builds do) and FX graph
        mode quantisation (``torch.ao.quantization``, which torch deprecates in favour of torchao).
    """
    import torch

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            import torch.ao.quantization.quantize_fx  # noqa: F401
    except ImportError:
        return False
    return INT8_ENGINE in torch.backends.quantized.supported_engines


@contextlib.contextmanager
def _engine():
    """torch's quantised engine set to :data:`INT8_ENGINE` while weights are packed for it, and
    torch's deprecation notices of ``torch.ao.quantization`` silenced (int8_available's docstring)."""
    import torch

    before = torch.backends.quantized.engine
    torch.backends.quantized.engine = INT8_ENGINE
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=DeprecationWarning, message="torch.ao.quantization")
            warnings.filterwarnings("ignore", category=UserWarning, message="torch.quantize_per_tensor")
            yield
    finally:
        torch.backends.quantized.engine = before


def _float_module_names(network) -> list[str]:
    """The modules that stay float32: the first convolution and every transposed convolution."""
    import torch

    names = [name for name, m in network.named_modules() if isinstance(m, torch.nn.ConvTranspose2d)]
    first = next(name for name, m in network.named_modules() if isinstance(m, torch.nn.Conv2d))
    return [f"n.{name}" for name in [first, *names]]


def _prepared(network, observer, example):
    """The network's feature extractor (:meth:`~.nets.unet.UNet.features`) traced and prepared for
    quantisation, an ``observer`` after every quantised activation."""
    import torch

    with _engine():
        from torch.ao.quantization import QConfig, QConfigMapping
        from torch.ao.quantization.observer import PerChannelMinMaxObserver
        from torch.ao.quantization.quantize_fx import prepare_fx

    class Features(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.n = net

        def forward(self, x):
            return self.n.features(x)

    weights = PerChannelMinMaxObserver.with_args(dtype=torch.qint8, qscheme=torch.per_channel_symmetric)
    mapping = QConfigMapping().set_global(QConfig(activation=observer, weight=weights))
    for name in _float_module_names(network):
        mapping = mapping.set_module_name(name, None)
    model = Features(copy.deepcopy(network).float().eval()).eval()
    with _engine():
        return prepare_fx(model, mapping, example_inputs=(example,))


def _activation_observers(prepared) -> list:
    with _engine():
        from torch.ao.quantization.observer import ObserverBase

    return [m for _, m in prepared.named_modules() if isinstance(m, ObserverBase)]


def _check_runner(runner) -> None:
    # what a UNetRunner has and calibration reads (runner.py builds on this module, not the reverse)
    if not all(hasattr(runner, name) for name in ("network", "scale", "manifest", "with_precision")):
        raise TypeError(f"segmenter must be a histostudy.learning.UNetRunner, got {type(runner).__name__}")


def _network_input(segmenter, frame: Frame):
    """``frame`` as the network reads it: standardised at its input scale, padded as the U-Net pads."""
    import torch

    from ..preprocess import prepare_image

    return segmenter.network.pad(torch.from_numpy(prepare_image(frame.image, segmenter.scale))[None, None])


def calibrate_int8(segmenter, frames: Sequence[Frame]) -> dict:
    """The quantisation parameters of a U-Net's activations on frames (docs/inference.md, "int8").

    Args:
        segmenter: the :class:`~histostudy.learning.UNetRunner` of the checkpoint (any precision;
            its network, input scale and manifest are read).
        frames: full frames, as the network sees them (e.g. of the checkpoint's validation split).

    Returns:
        The calibration: a dict for ``UNetRunner(..., precision="int8", int8_calibration=...)`` and
        :func:`save_int8_calibration`, with the checkpoint's SHA-256, torch's version and the number of frames.

    Raises:
        TypeError: ``segmenter`` is not a :class:`~histostudy.learning.UNetRunner`.
        ValueError: ``frames`` is empty or holds something other than
            :class:`~histostudy.imaging.frame.Frame` objects.
    """
    import torch

    with _engine():
        from torch.ao.quantization.observer import HistogramObserver
    _check_runner(segmenter)
    frames = list(frames)
    if not frames or not all(isinstance(f, Frame) for f in frames):
        raise ValueError(f"frames must be a non-empty sequence of Frames, got {len(frames)} items")
    inputs = [_network_input(segmenter, f) for f in frames]
    prepared = _prepared(segmenter.network, HistogramObserver.with_args(reduce_range=False), inputs[0])
    with torch.no_grad(), _engine():
        for x in inputs:
            prepared(x)
    qparams = [[float(s), int(z)] for s, z in (obs.calculate_qparams() for obs in _activation_observers(prepared))]
    return {"format": INT8_CALIBRATION_FORMAT, "checkpoint_sha256": (segmenter.manifest or {}).get("sha256"),
            "engine": INT8_ENGINE, "torch": torch.__version__, "frames": len(frames),
            "float_modules": _float_module_names(segmenter.network), "activation_qparams": qparams}


class Int8Features:
    """The int8 feature extractor of a U-Net (docs/inference.md, "int8"), rebuilt from its calibration
    (:func:`calibrate_int8` or :func:`load_int8_calibration`).

    ``features(x)``: float32 ``(1, channels, rows, cols)`` features of the last decoder block (the
    input to the head) of a float32 ``(1, 1, rows, cols)`` network input whose sides are multiples
    of the U-Net's ``pad_multiple``. Safe to call from several threads at once.
    """

    def __init__(self, segmenter, calibration: dict):
        import torch

        if not int8_available():
            raise ValueError(f"this torch ({torch.__version__}) has no {INT8_ENGINE!r} quantised engine: "
                             f"use precision 'float32'")
        _check_calibration(calibration, segmenter)
        with _engine():
            from torch.ao.quantization.observer import MinMaxObserver
            from torch.ao.quantization.quantize_fx import convert_fx
        m = segmenter.network.pad_multiple
        prepared = _prepared(segmenter.network, MinMaxObserver.with_args(reduce_range=False),
                             torch.zeros(1, 1, 2 * m, 2 * m))
        observers = _activation_observers(prepared)
        qparams = calibration["activation_qparams"]
        if len(observers) != len(qparams):
            raise ValueError(f"calibration holds {len(qparams)} activations, this torch's graph of the network "
                             f"{len(observers)}: calibrate again with this torch (histostudy calibrate-int8)")
        for obs, (scale, zero_point) in zip(observers, qparams):
            obs.calculate_qparams = _stored(scale, zero_point)
        with _engine():
            self._model = convert_fx(prepared)

    def features(self, x):
        import torch

        with torch.no_grad():
            return self._model(x)


def _stored(scale: float, zero_point: int):
    """An observer's ``calculate_qparams`` returning the calibration's values exactly."""
    import torch

    def calculate_qparams():
        return torch.tensor([scale], dtype=torch.float32), torch.tensor([zero_point], dtype=torch.int32)

    return calculate_qparams


def _check_calibration(calibration, segmenter) -> None:
    if not isinstance(calibration, dict) or calibration.get("format") != INT8_CALIBRATION_FORMAT:
        raise ValueError(f"calibration must be a dict of format {INT8_CALIBRATION_FORMAT!r} (calibrate_int8), "
                         f"got {type(calibration).__name__} of format "
                         f"{calibration.get('format') if isinstance(calibration, dict) else None!r}")
    sha = (segmenter.manifest or {}).get("sha256")
    if calibration.get("checkpoint_sha256") != sha:
        raise ValueError(f"calibration is of the checkpoint with SHA-256 {calibration.get('checkpoint_sha256')!r}, "
                         f"the segmenter's is {sha!r}: calibrate this checkpoint (histostudy calibrate-int8)")
    qparams = calibration.get("activation_qparams")
    if not isinstance(qparams, list) or not all(
            isinstance(q, list) and len(q) == 2 and np.isfinite(q[0]) and q[0] > 0 and 0 <= q[1] <= 255
            for q in qparams):
        raise ValueError("calibration['activation_qparams'] must be a list of [scale > 0, zero point in 0..255]")


def int8_calibration_path(segmenter) -> Path | None:
    """Where the calibration of a checkpoint lives: ``<weights>.int8.json`` beside its weights.

    Args:
        segmenter: the :class:`~histostudy.learning.UNetRunner` of the checkpoint (its manifest is read).

    Returns:
        The path in ``data/models`` (it may not exist), or None for a network without a manifest.
    """
    from ..checkpoints import MODELS_DIR

    weights = (segmenter.manifest or {}).get("weights_file")
    return None if not weights else MODELS_DIR / (Path(weights).name.split(".")[0] + ".int8.json")


def load_int8_calibration(segmenter) -> dict | None:
    """The stored calibration of a checkpoint.

    Args:
        segmenter: the :class:`~histostudy.learning.UNetRunner` of the checkpoint.

    Returns:
        The calibration, or None where there is none or it is of another checkpoint (another SHA-256).
    """
    path = int8_calibration_path(segmenter)
    if path is None or not path.is_file():
        return None
    calibration = json.loads(path.read_text(encoding="utf-8"))
    sha = (segmenter.manifest or {}).get("sha256")
    return calibration if calibration.get("checkpoint_sha256") == sha else None


def save_int8_calibration(calibration: dict, path) -> Path:
    """Write a calibration as JSON, atomically, honouring the umask.

    Args:
        calibration: the dict of :func:`calibrate_int8`.
        path: the file to write (:func:`int8_calibration_path` is where runners look).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OSError: the file cannot be written.
    """
    from histostudy.core import atomic_write_json

    path = Path(path)
    atomic_write_json(path, calibration)
    return path
