"""The optimiser of a training run (SGD with momentum or Adam) and the tensors its checkpoints hold
(docs/training.md, "The training package").
"""

from __future__ import annotations

import torch

from ._config import TrainingConfig

__all__: list[str] = []


def _optimizer(cfg: TrainingConfig, net) -> torch.optim.Optimizer:
    """A fresh optimiser of ``net``'s parameters: Adam, or SGD with ``cfg.momentum``, at
    ``cfg.learning_rate``."""
    if cfg.optimizer == "adam":
        return torch.optim.Adam(net.parameters(), lr=cfg.learning_rate)
    return torch.optim.SGD(net.parameters(), lr=cfg.learning_rate, momentum=cfg.momentum)


def _set_learning_rate(opt: torch.optim.Optimizer, lr: float) -> None:
    """Set the learning rate of every parameter group of ``opt`` to ``lr``."""
    for group in opt.param_groups:
        group["lr"] = lr


def _optim_tensors(opt: torch.optim.Optimizer) -> dict:
    """The optimiser's per-parameter state as tensors (SGD's momentum; Adam's moments and step)."""
    out = {}
    for i, state in opt.state_dict()["state"].items():
        for name, value in state.items():
            if value is not None:
                out[f"optim.{i}.{name}"] = torch.as_tensor(value)
    return out


def _load_optim(opt: torch.optim.Optimizer, tensors: dict) -> None:
    """Load into ``opt`` the per-parameter state held by checkpoint ``tensors`` (``optim.`` entries)."""
    sd = opt.state_dict()
    state: dict = {}
    for key, value in tensors.items():
        if key.startswith("optim."):
            _, i, name = key.split(".", 2)
            state.setdefault(int(i), {})[name] = value
    sd["state"] = state
    opt.load_state_dict(sd)


def _model_tensors(net) -> dict:
    """``net``'s state dict as checkpoint tensors (``model.`` prefix)."""
    return {f"model.{k}": v for k, v in net.state_dict().items()}


def _model_state(tensors: dict) -> dict:
    """The network's state dict in checkpoint ``tensors`` (their ``model.`` entries, prefix dropped)."""
    return {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}
