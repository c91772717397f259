"""The transducer pose from the lab's own files (§II-B.3-4), what ``histostudy pose`` runs: frame files
(DICOM XA, ``.npy``, ``.png``/``.tif``) with their views, :func:`~.estimate.estimate_pose` on the
shipped learned stages, and the result as plain JSON (:func:`pose_record`; mm, 4x4
``T_carm_transducer``, the verdict's figures and the half-turn reading).
"""

from __future__ import annotations

import functools
import os
import weakref
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from histostudy.core import to_jsonable, world_frame_keys
from histostudy.imaging import View, load_frame, load_views
from histostudy.transducer import HALF_TURN, TransducerModel, half_turn_symmetric

from .estimate import estimate_pose
from .result import PoseResult

__all__ = ["frames_from_files", "half_turn_reading", "match_views", "pose_from_files", "pose_record"]

_DICOM_SUFFIXES = (".dcm", ".dicom", "")


def match_views(views: Sequence[View], frame_paths: Sequence[str | os.PathLike]) -> list[View]:
    """The view of each frame file: ``views`` in the same order when there are as many, else the
    view named as the file's stem. Raises ValueError (its message to follow the views file's name)
    when a file has none."""
    paths = [Path(p) for p in frame_paths]
    if len(views) == len(paths):
        return list(views)
    by_name = {v.name: v for v in views}
    missing = [p.name for p in paths if p.stem not in by_name]
    if missing:
        raise ValueError(f"holds {len(views)} views for {len(paths)} frame files and none named as the stem of "
                         f"{missing} (a view is matched by order, or by name = the file's stem)")
    return [by_name[p.stem] for p in paths]


def frames_from_files(frame_paths: Sequence[str | os.PathLike], views_path: str | os.PathLike | None = None, *,
                      frame_index: int | None = None, line_integrals: bool = False, resample: bool = False) -> list:
    """The frames of ``frame_paths``, each with its view: the ``views_path`` file's views in the
    same order (or the one named as the file's stem), else the DICOM file's own geometry tags."""
    paths = [Path(p) for p in frame_paths]
    if not paths:
        raise ValueError("frame_paths must name at least one frame file")
    views = None
    if views_path is not None:
        try:
            views = match_views(load_views(views_path), paths)
        except ValueError as exc:
            raise ValueError(f"views file {str(views_path)!r} {exc}") from None
    frames = []
    for i, path in enumerate(paths):
        if views is not None:
            view = views[i]
        elif path.suffix.lower() in _DICOM_SUFFIXES:
            view = View.from_dicom(path, frame_index=frame_index, name=path.stem)
        else:
            raise ValueError(f"frame {str(path)!r} carries no geometry (not DICOM): give its view in a views file")
        frames.append(load_frame(path, view, line_integrals=line_integrals, frame_index=frame_index,
                                 resample=resample))
    return frames


def pose_from_files(frame_paths: Sequence[str | os.PathLike], views_path: str | os.PathLike | None = None, *,
                    frame_index: int | None = None, line_integrals: bool = False, resample: bool = False,
                    model_spacing_mm: float = 0.47, seed: int = 0, model: TransducerModel | None = None,
                    **options) -> PoseResult:
    """:func:`~.estimate.estimate_pose` on the frames of :func:`frames_from_files`, with ``model``
    (e.g. the lab's transducer from its CAD meshes, :meth:`TransducerModel.from_meshes`; default the
    digital model at ``model_spacing_mm``, the paper's 0.47 mm), the shipped learned stages and
    ``numpy.random.default_rng(seed)``; ``options``: :class:`~.options.PoseConfig` fields. A
    refused fit comes back with its verdict (``raise_on_failure=False`` unless given)."""
    frames = frames_from_files(frame_paths, views_path, frame_index=frame_index, line_integrals=line_integrals,
                               resample=resample)
    options.setdefault("raise_on_failure", False)
    if model is None:
        model = TransducerModel.build(spacing_mm=model_spacing_mm)
    elif not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a TransducerModel, got {type(model).__name__}")
    return estimate_pose(frames, model, rng=np.random.default_rng(seed), **options)


def pose_record(result: PoseResult, frame_paths: Sequence[str | os.PathLike] = (), *,
                model: TransducerModel | None = None) -> dict:
    """The pose as plain JSON: ``frame`` and ``units`` (the C-arm/CBCT frame, DICOM LPS, mm;
    :func:`~histostudy.core.world_frame_keys`), ``T_carm_transducer`` (4x4, mm),
    ``focal_point_mm``, the cost, the verdict (accepted, reasons, per-view figures), the stage
    timings and ``half_turn`` (:func:`half_turn_reading`) for ``model``, the model the pose was
    estimated with (None: the paper's digital model, which :func:`pose_from_files` and the live
    receiver use when given none)."""
    verdict = result.verdict
    return to_jsonable({
        **world_frame_keys(),
        "frames": [str(p) for p in frame_paths],
        "T_carm_transducer": result.T_carm_transducer,
        "focal_point_mm": result.focal_point_mm,
        "cost": result.cost,
        "accepted": bool(verdict.ok),
        "verdict": {"reasons": list(verdict.reasons), "rms_distance_px": verdict.rms_distance_px,
                    "view_disagreement_mm": verdict.view_disagreement_mm,
                    "unexplained_fraction": verdict.unexplained_fraction},
        "timings_s": result.timings_s,
        "half_turn": half_turn_reading(result.T_carm_transducer, model),
    })


def half_turn_reading(T_carm_transducer, model: TransducerModel | None = None) -> dict:
    """The pose's other reading (§II-B.4): ``symmetric``, whether ``model`` (None: the paper's
    digital model) looks the same after a half turn about its axis, so that no image tells the two
    readings apart (:func:`~histostudy.transducer.half_turn_symmetric`, computed once per model);
    ``axis_carm``, that axis (the transducer's z, the beam axis; a unit vector in the C-arm frame);
    and ``T_carm_transducer_half_turn``, the pose turned half about it (4x4, mm): the same axis and,
    the focal point lying on it (the transducer frame's origin by convention, docs/architecture.md),
    the same focal point."""
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_carm_transducer must be a finite 4x4 transform (mm), got shape {T.shape}")
    turned = T.copy()
    turned[:3, :3] = T[:3, :3] @ HALF_TURN
    return to_jsonable({"symmetric": _default_model_symmetric() if model is None else _model_symmetric(model),
                        "axis_carm": T[:3, 2], "T_carm_transducer_half_turn": turned})


# Whether a model is half-turn symmetric, per model object: the check queries every model point
# (a fraction of a second), which a pose record per pair of the live stream must not pay again.
_SYMMETRIC: weakref.WeakKeyDictionary[TransducerModel, bool] = weakref.WeakKeyDictionary()


def _model_symmetric(model: TransducerModel) -> bool:
    if not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a TransducerModel or None, got {type(model).__name__}")
    if model not in _SYMMETRIC:
        _SYMMETRIC[model] = half_turn_symmetric(model)
    return _SYMMETRIC[model]


@functools.lru_cache(maxsize=1)
def _default_model_symmetric() -> bool:
    # the model pose_from_files builds when given none (model_spacing_mm's default)
    return half_turn_symmetric(TransducerModel.build(spacing_mm=0.47))
