"""The X-ray C-arm guided automatic targeting system for histotripsy of Wagner et al. (IEEE TBME 2023),
rebuilt in Python and reproduced on synthetic data. One subpackage per concern, lowest layer first
(docs/architecture.md, "Layers"): ``core``, ``geometry``, ``transducer``, ``imaging``, ``learning``,
``pose``, ``calibration``, ``robot``, ``treatment``, ``lab``, ``study`` (a folder per notebook),
``reporting`` (the batch run and its report) and ``cli`` (the command line)."""

__version__ = "0.3.0"
