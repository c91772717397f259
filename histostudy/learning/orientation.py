"""Transducer orientation relative to a view: azimuth and elevation (paper §II-B.4, eq. 4), their
mirror candidates, and the orientation sources (oracle, learned VGG19) behind :class:`OrientationSource`
(docs/learned-stages.md, "The orientation angles").
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from histostudy.core import stage
from histostudy.imaging import Frame, View

if TYPE_CHECKING:
    import torch

__all__ = [
    "N_ORIENTATION_CLASSES",
    "LearnedOrientation",
    "OracleOrientation",
    "OrientationSource",
    "angles_from_direction",
    "beam_direction_of_pose",
    "default_vgg19",
    "direction_candidates",
    "hemisphere_angles",
    "hemisphere_directions",
    "orientation_angle_error",
    "orientation_class",
    "select_direction",
    "wrap_angle",
]


def beam_direction_of_pose(T_carm_transducer) -> np.ndarray:
    """World unit vector from the transducer centre to its focal point (the transducer's ``-z``).

    Args:
        T_carm_transducer: ``(4, 4)`` pose mapping transducer -> C-arm (world) coordinates, mm.

    Returns:
        ``(3,)`` float64 unit vector in the C-arm frame.
    """
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    d = -T[:3, 2]
    return d / np.linalg.norm(d)


def wrap_angle(angle_rad):
    """Angle(s) wrapped to ``(-pi, pi]``; use for azimuth differences (azimuth wraps around).

    Args:
        angle_rad: an angle or an array of angles, rad.

    Returns:
        float64 array of the input's shape (a 0-d array for a scalar), rad in ``(-pi, pi]``.
    """
    wrapped = np.mod(np.asarray(angle_rad, dtype=np.float64) + np.pi, 2 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def angles_from_direction(direction, view: View) -> tuple[float, float]:
    """The azimuth and elevation of a world direction relative to a view (paper §II-B.4; the convention:
    docs/learned-stages.md, "The orientation angles").

    Args:
        direction: a world (C-arm frame) 3-vector, any length but zero.
        view: the :class:`~histostudy.imaging.carm.View` whose detector axes the angles refer to.

    Returns:
        ``(azimuth_rad, elevation_rad)``: azimuth in ``(-pi, pi]`` from the detector's column axis,
        elevation in ``[0, pi/2]`` from the beam axis, of the mirror pointing away from the detector.

    Raises:
        ValueError: ``direction`` is zero or not finite.
    """
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(d)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"direction must be a non-zero finite 3-vector, got {d.tolist()}")
    d_det = view.detector_axes @ (d / norm)
    if d_det[2] > 0:  # the mirror that points away from the detector
        d_det[2] = -d_det[2]
    azimuth = float(np.arctan2(d_det[1], d_det[0]))
    elevation = float(np.arccos(np.clip(-d_det[2], -1.0, 1.0)))
    return azimuth, elevation


def direction_candidates(azimuth_rad: float, elevation_rad: float, view: View) -> np.ndarray:
    """Eq. 4: the two world unit directions that an azimuth and elevation allow in a view.

    Args:
        azimuth_rad: azimuth relative to ``view``, rad.
        elevation_rad: elevation relative to ``view``, rad.
        view: the :class:`~histostudy.imaging.carm.View` the angles refer to.

    Returns:
        ``(2, 3)`` world (C-arm frame) unit directions: row 0 points away from the detector (the
        canonical mirror), row 1 is its mirror image.

    Raises:
        ValueError: an angle is not finite.
    """
    if not (np.isfinite(azimuth_rad) and np.isfinite(elevation_rad)):
        raise ValueError(f"azimuth_rad and elevation_rad must be finite, got {azimuth_rad!r}, {elevation_rad!r}")
    s = np.sin(elevation_rad)
    base = np.array([np.cos(azimuth_rad) * s, np.sin(azimuth_rad) * s, 0.0])
    c = np.cos(elevation_rad)
    R = view.detector_axes  # rows: detector axes in world; R.T maps detector -> world
    return np.stack([R.T @ (base + [0, 0, -c]), R.T @ (base + [0, 0, c])])


def select_direction(candidates: Sequence[np.ndarray]) -> tuple[np.ndarray, tuple[int, ...], float]:
    """Resolve the mirror ambiguity across views (§II-B.4): one candidate per view, those that agree best
    (smallest mean pairwise angle). With one view the ambiguity cannot be resolved: the canonical
    candidate is returned and the caller should try both (the pose search does).

    Args:
        candidates: per view, its ``(2, 3)`` world directions (:func:`direction_candidates`).

    Returns:
        ``(direction, indices, angle_rad)``: the chosen directions' normalised mean (world unit
        vector), the chosen row of each view, and their mean pairwise angle in rad.

    Raises:
        ValueError: ``candidates`` is empty, or an entry does not hold 6 numbers.
    """
    cands = [np.asarray(c, dtype=np.float64).reshape(2, 3) for c in candidates]
    if not cands:
        raise ValueError("candidates must hold the direction candidates of at least one view")
    if len(cands) == 1:
        return cands[0][0] / np.linalg.norm(cands[0][0]), (0,), 0.0
    best: tuple[float, tuple[int, ...], list] = (float("inf"), (), [])
    for choice in itertools.product((0, 1), repeat=len(cands)):
        dirs = [c[i] / np.linalg.norm(c[i]) for c, i in zip(cands, choice)]
        angles = [np.arccos(np.clip(a @ b, -1, 1)) for a, b in itertools.combinations(dirs, 2)]
        score = float(np.mean(angles))
        if score < best[0]:
            best = (score, choice, dirs)
    score, choice, dirs = best
    mean = np.sum(dirs, axis=0)
    return mean / np.linalg.norm(mean), tuple(choice), score


@runtime_checkable
class OrientationSource(Protocol):
    """Gives the transducer's azimuth and elevation (rad) relative to a frame's view."""

    def estimate(self, frame: Frame, rng: np.random.Generator) -> tuple[float, float]: ...


# Gaussian errors whose mean absolute value is the paper's MAE: MAE = sd * sqrt(2 / pi).
_MAE_TO_SD = np.sqrt(np.pi / 2.0)


@dataclass(frozen=True)
class OracleOrientation:
    """Azimuth and elevation from a synthetic frame's true pose, plus Gaussian errors.

    By default the errors' mean absolute values are the paper's regression MAE (§III: 1.06 deg
    azimuth, 2.34 deg elevation), so the initialisation sees what the learned network gave. The
    noisy elevation is folded back into ``[0, pi/2]``. Needs ``frame.T_carm_transducer``.

    Args:
        azimuth_mae_deg: mean absolute azimuth error, deg (0: exact).
        elevation_mae_deg: mean absolute elevation error, deg (0: exact).

    Raises:
        ValueError: an error is negative or not finite; :meth:`estimate` of a frame without
            ``T_carm_transducer``.
    """

    azimuth_mae_deg: float = 1.06
    elevation_mae_deg: float = 2.34

    def __post_init__(self):
        for name in ("azimuth_mae_deg", "elevation_mae_deg"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")

    @stage("orient")
    def estimate(self, frame: Frame, rng: np.random.Generator) -> tuple[float, float]:
        if frame.T_carm_transducer is None:
            raise ValueError(f"OracleOrientation needs a synthetic frame with T_carm_transducer; view "
                             f"{frame.view.name!r} has none (use a learned orientation source for real frames)")
        az, el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        az += np.deg2rad(rng.normal(0.0, self.azimuth_mae_deg * _MAE_TO_SD))
        el += np.deg2rad(rng.normal(0.0, self.elevation_mae_deg * _MAE_TO_SD))
        el = abs(el)
        if el > np.pi / 2:
            el = np.pi - el
        return float(wrap_angle(az)), float(el)


# --- the learned stage: 36 hemisphere classes and the VGG19 regressor (§II-B.4) -------------

#: Number of orientation classes of the paper's classifier (§II-B.4).
N_ORIENTATION_CLASSES = 36

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def hemisphere_angles(n: int = N_ORIENTATION_CLASSES) -> np.ndarray:
    """``(n, 2)`` azimuth and elevation (rad) of ``n`` near-equidistant directions on the hemisphere
    pointing away from the detector (§II-B.4: 36 classes sampled equidistantly).

    A Fibonacci lattice: direction ``i`` has ``cos(elevation) = 1 - (i + 1/2) / n`` (equal areas of
    the hemisphere per point) and azimuth ``i`` times the golden angle, wrapped to ``(-pi, pi]``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n must be an integer >= 2, got {n!r}")
    i = np.arange(int(n), dtype=np.float64)
    elevation = np.arccos(1.0 - (i + 0.5) / n)
    azimuth = wrap_angle(i * _GOLDEN_ANGLE)
    return np.column_stack([azimuth, elevation])


def _detector_direction(azimuth_rad, elevation_rad) -> np.ndarray:
    az, el = np.asarray(azimuth_rad, dtype=np.float64), np.asarray(elevation_rad, dtype=np.float64)
    return np.stack([np.cos(az) * np.sin(el), np.sin(az) * np.sin(el), -np.cos(el)], axis=-1)


def hemisphere_directions(n: int = N_ORIENTATION_CLASSES) -> np.ndarray:
    """``(n, 3)`` unit directions in the detector frame ``(e_u, e_v, e_w)`` of :func:`hemisphere_angles`
    (their ``e_w`` components are negative: pointing away from the detector)."""
    a = hemisphere_angles(n)
    return _detector_direction(a[:, 0], a[:, 1])


def orientation_angle_error(azimuth_rad, elevation_rad, reference_azimuth_rad, reference_elevation_rad):
    """Angle between the directions two ``(azimuth, elevation)`` pairs of one view stand for.

    The error that matters to the pose initialisation: unlike the azimuth error alone it is small
    near elevation 0, where the azimuth is ill-defined.

    Args:
        azimuth_rad: estimated azimuth(s), rad.
        elevation_rad: estimated elevation(s), rad.
        reference_azimuth_rad: true azimuth(s), rad.
        reference_elevation_rad: true elevation(s), rad (all four broadcast together).

    Returns:
        The angle(s) in rad, in ``[0, pi]``: a float64 array of the broadcast shape.
    """
    a = _detector_direction(azimuth_rad, elevation_rad)
    b = _detector_direction(reference_azimuth_rad, reference_elevation_rad)
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


def orientation_class(azimuth_rad: float, elevation_rad: float, n: int = N_ORIENTATION_CLASSES) -> int:
    """Index of the hemisphere direction (:func:`hemisphere_directions`) nearest to the given angles."""
    if not (np.isfinite(azimuth_rad) and np.isfinite(elevation_rad)):
        raise ValueError(f"azimuth_rad and elevation_rad must be finite, got {azimuth_rad!r}, {elevation_rad!r}")
    return int(np.argmax(hemisphere_directions(n) @ _detector_direction(azimuth_rad, elevation_rad)))


@dataclass(frozen=True, eq=False)
class LearnedOrientation:
    """The VGG19 regressor of §II-B.4 as an :class:`OrientationSource`.

    The frame is downscaled by ``network.scale`` (0.25: 1240x960 -> 310x240) and standardised
    (:func:`histostudy.learning.preprocess.prepare_image`); the network returns azimuth and elevation in rad
    relative to the frame's view, in the convention of :func:`angles_from_direction`. The raw
    azimuth is wrapped to ``(-pi, pi]`` and the elevation folded into ``[0, pi/2]``. ``rng`` is
    accepted for the protocol and unused (inference is deterministic).

    Build it with :meth:`load` from a checkpoint (:mod:`histostudy.learning.checkpoints`), or get the
    shipped one from :func:`default_vgg19`.

    Args:
        network: the VGG19 regressor (:class:`~histostudy.learning.nets.vgg.VGG19`, ``head="regressor"``).
        scale: the network's input scale (network pixels per frame pixel).
        manifest: the checkpoint's manifest, None for a network without one.

    Raises:
        TypeError: :meth:`estimate_many` of something other than a
            :class:`~histostudy.imaging.frame.Frame`.
        ValueError: :meth:`load` of a checkpoint that is no VGG19 regressor or fails its checks;
            :meth:`estimate_many` of frames of different shapes in one batch.
    """

    network: torch.nn.Module = field(repr=False)
    scale: float = 0.25
    manifest: dict | None = field(default=None, repr=False)

    @classmethod
    def load(cls, path) -> LearnedOrientation:
        """From a VGG19 regressor checkpoint (hash and configuration checked)."""
        from .checkpoints import load_network

        net, manifest = load_network(path)
        config = manifest["config"]  # the network's, as load_network built it
        if config.get("arch") != "vgg19" or config.get("head") != "regressor":
            raise ValueError(f"checkpoint {str(path)!r} holds {config}, expected a VGG19 regressor")
        return cls(network=net, scale=float(manifest.get("input_scale", 0.25)), manifest=manifest)

    def estimate(self, frame: Frame, rng: np.random.Generator | None = None) -> tuple[float, float]:
        return self.estimate_many([frame])[0]

    @stage("orient")
    def estimate_many(self, frames: Sequence[Frame], batch_size: int = 8) -> list[tuple[float, float]]:
        """Angles of several frames in batches: ``[(azimuth_rad, elevation_rad), ...]``."""
        import torch

        from .preprocess import prepare_image

        out = []
        self.network.eval()
        for start in range(0, len(frames), batch_size):
            batch = []
            for frame in frames[start:start + batch_size]:
                if not isinstance(frame, Frame):
                    raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
                batch.append(prepare_image(frame.image, self.scale))
            shapes = {b.shape for b in batch}
            if len(shapes) != 1:
                raise ValueError(f"frames in one batch must share a shape, got {sorted(shapes)}")
            with torch.no_grad():
                pred = self.network(torch.from_numpy(np.stack(batch))[:, None]).double().numpy()
            for az, el in pred:
                el = abs(float(el)) % np.pi
                out.append((float(wrap_angle(az)), float(np.pi - el if el > np.pi / 2 else el)))
        return out


def default_vgg19() -> LearnedOrientation | None:
    """The shipped VGG19 regressor (``data/models/vgg19_standard``).

    Returns:
        Its :class:`LearnedOrientation`, or None (with a warning) when the weights are missing or
        fail their hash or configuration check.
    """
    from .checkpoints import load_shipped

    return load_shipped("vgg19_standard", LearnedOrientation.load, "VGG19")
