"""C-arm projection geometry (§II-A, eq. 1-2): a :class:`View` projects world points (CBCT frame, LPS, mm) to
pixels, made from gantry angles, a DICOM object or a calibration file. Conventions (pixel centres, angle
signs, the detector frame): docs/imaging.md, "Frames and conventions"."""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.linalg

from histostudy.core import atomic_write_json
from histostudy.geometry import as_points, check_rotation, rotation_about_axis

__all__ = ["View", "default_biplane", "load_views", "save_views"]

VIEWS_FORMAT = "histostudy.views"
VIEWS_FORMAT_VERSION = 1

# Largest condition number of P[:, :3] still accepted as a projection (beyond: a singular view).
_MAX_CONDITION = 1e12
#: Points (mm, C-arm frame) whose projections compare two views: the isocentre and the corners of a
#: 100 mm cube around it, the region where the transducer's focal point is sought.
_PROBE_POINTS_MM = np.array([[0.0, 0.0, 0.0]] + [[x, y, z] for x in (-50.0, 50.0) for y in (-50.0, 50.0)
                                                 for z in (-50.0, 50.0)])


@dataclass(frozen=True, eq=False)
class View:
    """One calibrated projection geometry.

    Attributes:
        P: 3x4 projection matrix, world (CBCT) mm -> homogeneous pixels (eq. 1).
        shape: detector image shape ``(rows, cols)`` in pixels.
        pixel_mm: detector pixel pitch in mm (at the detector, not at the isocentre).
        name: a label, e.g. ``"A"`` or ``"B"`` for the biplane planes.
        gantry: the gantry parameters the view was built from (None for a user's calibrated P).
    """

    P: np.ndarray
    shape: tuple[int, int]
    pixel_mm: float
    name: str = ""
    gantry: dict | None = field(default=None)

    def __post_init__(self):
        P = np.array(self.P, dtype=np.float64)
        if P.shape != (3, 4):
            raise ValueError(f"P must be a 3x4 projection matrix, got shape {P.shape}")
        if not np.all(np.isfinite(P)):
            raise ValueError(f"P must be finite, got {P.tolist()}")
        M = P[:, :3]
        cond = np.linalg.cond(M)
        if not np.isfinite(cond) or cond > _MAX_CONDITION:
            raise ValueError(
                f"P describes a singular view: P[:, :3] has condition number {cond:.3g} "
                f"(expected < {_MAX_CONDITION:g}); P = {P.tolist()}"
            )
        # P and -P give the same pixels; fix the sign so that w > 0 in front of the source. The
        # isocentre (world origin) is in front of the source for every C-arm view.
        if P[2, 3] < 0:
            P = -P
        P.setflags(write=False)
        object.__setattr__(self, "P", P)
        try:
            rows, cols = (int(s) for s in self.shape)
        except (TypeError, ValueError):
            raise ValueError(f"shape must be (rows, cols), got {self.shape!r}") from None
        if rows <= 0 or cols <= 0 or tuple(self.shape) != (rows, cols):
            raise ValueError(f"shape must be two positive integers (rows, cols), got {self.shape!r}")
        object.__setattr__(self, "shape", (rows, cols))
        pixel = float(self.pixel_mm)
        if not np.isfinite(pixel) or pixel <= 0:
            raise ValueError(f"pixel_mm must be a finite positive pixel pitch in mm, got {self.pixel_mm!r}")
        object.__setattr__(self, "pixel_mm", pixel)

    # --- construction -------------------------------------------------------------------------

    @classmethod
    def from_gantry(
        cls,
        primary_deg: float,
        secondary_deg: float = 0.0,
        *,
        source_isocenter_mm: float = 785.0,
        source_detector_mm: float = 1200.0,
        shape: tuple[int, int] = (960, 1240),
        pixel_mm: float = 0.308,
        principal_point: tuple[float, float] | None = None,
        name: str = "",
    ) -> View:
        """An ideal C-arm view from gantry angles (see the module docstring for the convention).

        Args:
            primary_deg: LAO (+) / RAO (-) angle in degrees.
            secondary_deg: CRAN (+) / CAUD (-) angle in degrees.
            source_isocenter_mm: focal spot to isocentre distance (SOD).
            source_detector_mm: focal spot to detector distance (SID); must exceed SOD.
            shape: detector ``(rows, cols)``; default is an Artis-zee-like 1240x960 readout.
            pixel_mm: detector pixel pitch in mm.
            principal_point: ``(u, v)`` of the principal ray; default the detector centre.
            name: label of the view.
        """
        for arg, value in (("primary_deg", primary_deg), ("secondary_deg", secondary_deg)):
            if not np.isfinite(value):
                raise ValueError(f"{arg} must be a finite angle in degrees, got {value!r}")
        sod, sdd = float(source_isocenter_mm), float(source_detector_mm)
        if not (np.isfinite(sod) and sod > 0):
            raise ValueError(f"source_isocenter_mm must be finite and > 0, got {source_isocenter_mm!r}")
        if not (np.isfinite(sdd) and sdd > sod):
            raise ValueError(
                f"source_detector_mm must be finite and larger than source_isocenter_mm ({sod} mm), "
                f"got {source_detector_mm!r}"
            )
        pixel = float(pixel_mm)
        if not (np.isfinite(pixel) and pixel > 0):
            raise ValueError(f"pixel_mm must be a finite detector pixel pitch > 0 (mm), got {pixel_mm!r}")
        rows, cols = shape
        if principal_point is None:
            principal_point = ((cols - 1) / 2.0, (rows - 1) / 2.0)
        cu, cv = (float(c) for c in principal_point)
        # Detector frame at PA (0, 0): beam anterior (-y), rows towards the feet (-z).
        e_u0, e_v0, e_w0 = np.array([-1.0, 0, 0]), np.array([0, 0, -1.0]), np.array([0, -1.0, 0])
        alpha, beta = np.deg2rad(primary_deg), np.deg2rad(secondary_deg)
        R_gantry = rotation_about_axis([0, 0, 1], alpha) @ rotation_about_axis([1, 0, 0], -beta)
        R_cam_world = np.stack([R_gantry @ e_u0, R_gantry @ e_v0, R_gantry @ e_w0])
        source = -sod * (R_gantry @ e_w0)
        f_px = sdd / float(pixel_mm)
        K = np.array([[f_px, 0.0, cu], [0.0, f_px, cv], [0.0, 0.0, 1.0]])
        P = K @ np.hstack([R_cam_world, (-R_cam_world @ source)[:, None]])
        gantry = {
            "primary_deg": float(primary_deg),
            "secondary_deg": float(secondary_deg),
            "source_isocenter_mm": sod,
            "source_detector_mm": sdd,
            "principal_point": [cu, cv],
        }
        return cls(P=P, shape=(rows, cols), pixel_mm=pixel_mm, name=name, gantry=gantry)

    @classmethod
    def from_matrix(cls, P, shape: tuple[int, int], pixel_mm: float, name: str = "") -> View:
        """A view from a user's calibrated 3x4 matrix (e.g. from a C-arm calibration phantom)."""
        return cls(P=P, shape=shape, pixel_mm=pixel_mm, name=name)

    @classmethod
    def from_krt(cls, K, R, t, shape: tuple[int, int], pixel_mm: float, name: str = "") -> View:
        """A view from a calibration's intrinsics and pose: ``P = K @ [R | t]`` (eq. 1).

        ``K``: 3x3 upper-triangular intrinsics in pixels (focal lengths > 0, principal point in
        ``K[:2, 2]``); ``R`` (3x3 rotation) and ``t`` (3, mm) map world (CBCT) points into the
        camera frame, ``x_cam = R @ x + t``, with the camera's z along the beam, x along image
        columns and y along rows (OpenCV's convention).
        """
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[2, 2] <= 0:
            raise ValueError(f"K must be a finite 3x3 intrinsic matrix with K[2, 2] > 0, got {np.asarray(K).tolist()}")
        K = K / K[2, 2]
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"K must be upper triangular with positive focal lengths (pixels), got {K.tolist()}")
        R = check_rotation(R, "R")
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"t must be 3 finite numbers (mm), got {np.asarray(t).tolist()}")
        return cls(P=K @ np.hstack([R, t[:, None]]), shape=shape, pixel_mm=pixel_mm, name=name)

    @classmethod
    def from_dicom(cls, dataset, *, frame_index: int | None = None, name: str = "") -> View:
        """The view a DICOM XA/RF object records (a pydicom dataset or a file path).

        Reads the positioner angles, the source distances, ``ImagerPixelSpacing`` and the image
        size (:mod:`.io.geometry`, which documents the conventions: those of
        :meth:`from_gantry`), from frame ``frame_index``'s functional groups in an enhanced object.
        Unequal row and column spacings give unequal focal lengths; ``pixel_mm`` is the column
        spacing. A missing attribute raises a ValueError naming it and its tag.
        """
        from .io.geometry import gantry_from_dicom

        source = "the DICOM object"
        if isinstance(dataset, (str, os.PathLike)):
            from .io.xray import read_dicom_file

            source = str(dataset)
            dataset = read_dicom_file(dataset, stop_before_pixels=True)  # its failures name the file
        g = gantry_from_dicom(dataset, frame_index, source)
        row_mm, col_mm = g["pixel_mm"]
        view = cls.from_gantry(g["primary_deg"], g["secondary_deg"], source_isocenter_mm=g["source_isocenter_mm"],
                               source_detector_mm=g["source_detector_mm"], shape=g["shape"], pixel_mm=col_mm,
                               name=name)
        assert view.gantry is not None
        gantry = dict(view.gantry, pixel_spacing_mm=[row_mm, col_mm])
        # rows: focal length SID / row spacing instead of / column spacing, about the principal point
        ratio, cv = col_mm / row_mm, view.gantry["principal_point"][1]
        rows = np.array([[1.0, 0.0, 0.0], [0.0, ratio, cv * (1.0 - ratio)], [0.0, 0.0, 1.0]])
        return cls(P=rows @ view.P, shape=view.shape, pixel_mm=col_mm, name=name, gantry=gantry)

    def scaled(self, factor: float) -> View:
        """The view of the same geometry on an image resampled by ``factor`` (0.25: 1240x960 -> 310x240).

        Keeps the pixel-centre convention: ``u' = factor * u + (factor - 1) / 2``.
        """
        factor = float(factor)
        if not np.isfinite(factor) or factor <= 0:
            raise ValueError(f"factor must be a finite positive scale, got {factor!r}")
        rows, cols = (int(round(s * factor)) for s in self.shape)
        if rows < 1 or cols < 1:
            raise ValueError(f"factor {factor} shrinks the {self.shape} detector to nothing")
        offset = (factor - 1.0) / 2.0
        S = np.array([[factor, 0.0, offset], [0.0, factor, offset], [0.0, 0.0, 1.0]])
        return View(P=S @ self.P, shape=(rows, cols), pixel_mm=self.pixel_mm / factor, name=self.name,
                    gantry=None)

    # --- geometry -----------------------------------------------------------------------------

    @cached_property
    def _M_inv(self) -> np.ndarray:
        return np.linalg.inv(self.P[:, :3])

    @cached_property
    def source_mm(self) -> np.ndarray:
        """X-ray focal spot position in world mm (the null space of ``P``)."""
        return -self._M_inv @ self.P[:, 3]

    @cached_property
    def principal_direction(self) -> np.ndarray:
        """Unit vector along the principal ray, from the source towards the detector."""
        m3 = self.P[2, :3]
        return m3 / np.linalg.norm(m3)

    @cached_property
    def decomposition(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(K, R_cam_world, source_mm)`` with ``P ~ K @ R @ [I | -source]``, K upper triangular, K[2,2]=1.

        ``R_cam_world``'s rows are the detector axes ``e_u`` (columns), ``e_v`` (rows) and ``e_w``
        (beam direction) in world coordinates.
        """
        K, R = scipy.linalg.rq(self.P[:, :3])
        signs = np.diag(np.sign(np.diag(K)))
        K, R = K @ signs, signs @ R
        if np.linalg.det(R) < 0:
            # P is only defined up to sign; a left-handed R means the detector axes are mirrored.
            raise ValueError("P has a mirrored (left-handed) detector frame; flip one image axis")
        return K / K[2, 2], R, self.source_mm

    @property
    def detector_axes(self) -> np.ndarray:
        """3x3 array whose rows are the world directions of the column (u), row (v) and beam axes."""
        return self.decomposition[1]

    def project_homogeneous(self, points_mm) -> np.ndarray:
        """``(n, 3)`` homogeneous image coordinates ``[u w, v w, w]`` of world points (eq. 1)."""
        pts = as_points(points_mm)
        return pts @ self.P[:, :3].T + self.P[:, 3]

    def project(self, points_mm) -> np.ndarray:
        """``(n, 2)`` pixel coordinates ``(u, v)`` (u along columns) of world points, eq. 1-2."""
        uvw = self.project_homogeneous(points_mm)
        return uvw[:, :2] / uvw[:, 2:3]

    def in_image(self, pixels) -> np.ndarray:
        """Boolean mask of pixel coordinates ``(n, 2)`` that fall on the detector."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        rows, cols = self.shape
        return (px[:, 0] >= -0.5) & (px[:, 0] < cols - 0.5) & (px[:, 1] >= -0.5) & (px[:, 1] < rows - 0.5)

    def ray_directions(self, pixels) -> np.ndarray:
        """Unit world directions ``(n, 3)`` of the rays from the source through pixel coordinates."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        homog = np.hstack([px, np.ones((len(px), 1))])
        d = homog @ self._M_inv.T
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def pixel_footprint_mm2(self, points_mm) -> np.ndarray:
        """Area in mm², perpendicular to the ray, that one detector pixel covers at each world point.

        For a cone beam the solid angle of pixel ``(u, v)`` is ``|det M^-1| / |M^-1 [u, v, 1]|^3``;
        at distance ``d`` from the source this is ``|w|^3 / (|det M| d)`` mm², exact for any P.
        The splatting renderer divides a point's attenuation-weighted area by it to get a line
        integral.
        """
        pts = as_points(points_mm)
        w = pts @ self.P[2, :3] + self.P[2, 3]
        d = np.linalg.norm(pts - self.source_mm, axis=1)
        return np.abs(w) ** 3 / (abs(np.linalg.det(self.P[:, :3])) * d)

    def projection_distance_mm(self, other: View) -> float:
        """How far this view's geometry is from ``other``'s where it matters: the largest distance
        between the two projections of the isocentre and of the corners of a 100 mm cube around it
        (the region where the focal point is sought), in mm at the isocentre (pixels times the size
        of ``other``'s pixel there), so that one tolerance serves any detector.

        Args:
            other: the view compared with (e.g. a calibrated one, this one from an object's tags).

        Returns:
            The distance in mm (0 for the same projection).

        Raises:
            TypeError: ``other`` is not a View.
        """
        if not isinstance(other, View):
            raise TypeError(f"other must be a histostudy.imaging.View, got {type(other).__name__}")
        px = float(np.max(np.linalg.norm(self.project(_PROBE_POINTS_MM) - other.project(_PROBE_POINTS_MM), axis=1)))
        return px * float(np.sqrt(other.pixel_footprint_mm2(np.zeros(3))[0]))

    # --- serialisation ------------------------------------------------------------------------

    def to_dict(self) -> dict:
        out = {"name": self.name, "P": self.P.tolist(), "shape": list(self.shape), "pixel_mm": self.pixel_mm}
        if self.gantry is not None:
            out["gantry"] = dict(self.gantry)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> View:
        """A view from :meth:`to_dict`'s form; only ``P``, ``shape`` and ``pixel_mm`` are required."""
        if not isinstance(data, dict):
            raise ValueError(f"a view must be a JSON object, got {type(data).__name__}")
        missing = [k for k in ("P", "shape", "pixel_mm") if k not in data]
        if missing:
            raise ValueError(f"view {data.get('name', '')!r} lacks {missing} (needs P, shape, pixel_mm)")
        return cls(P=data["P"], shape=tuple(data["shape"]), pixel_mm=data["pixel_mm"],
                   name=str(data.get("name", "")), gantry=data.get("gantry"))

    def __repr__(self) -> str:
        geo = ""
        if self.gantry:
            geo = f", primary={self.gantry['primary_deg']:+.1f}deg, secondary={self.gantry['secondary_deg']:+.1f}deg"
        return f"View(name={self.name!r}, shape={self.shape}, pixel_mm={self.pixel_mm:g}{geo})"


def default_biplane(**kwargs) -> tuple[View, View]:
    """The paper's biplane set-up (§II-D): plane A at -45 deg (RAO 45) and plane B at +45 deg (LAO 45).

    Args:
        **kwargs: passed to :meth:`View.from_gantry` for both planes (source-object and
            source-image distances in mm, detector shape in pixels, pixel size in mm).

    Returns:
        The views ``(A, B)``.

    Raises:
        ValueError: a keyword argument out of range (as :meth:`View.from_gantry` raises it).
    """
    return (View.from_gantry(-45.0, 0.0, name="A", **kwargs), View.from_gantry(45.0, 0.0, name="B", **kwargs))


def save_views(path: str | os.PathLike, views: Iterable[View]) -> Path:
    """Views written as JSON, atomically: ``{"format", "version", "views": [...]}``.

    Args:
        path: the file to write.
        views: the :class:`View` objects.

    Returns:
        The path written.

    Raises:
        TypeError: an element of ``views`` is not a View.
        OSError: the file cannot be written.
    """
    views = list(views)
    for i, v in enumerate(views):
        if not isinstance(v, View):
            raise TypeError(f"views[{i}] must be a View, got {type(v).__name__}")
    return atomic_write_json(path, {"format": VIEWS_FORMAT, "version": VIEWS_FORMAT_VERSION,
                                    "views": [v.to_dict() for v in views]})


def load_views(path: str | os.PathLike) -> list[View]:
    """Views read from JSON.

    Args:
        path: the file :func:`save_views` writes, or a bare list of view objects (e.g.
            ``[{"name": "A", "P": [[...], [...], [...]], "shape": [960, 1240], "pixel_mm": 0.308}]``;
            ``P`` is the 3x4 projection of eq. 1-2, C-arm mm -> pixels).

    Returns:
        The views, in the file's order.

    Raises:
        OSError: the file cannot be read.
        ValueError: the JSON is invalid, names another format, holds no views, or a view is invalid.
    """
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    if isinstance(data, dict):
        if data.get("format") != VIEWS_FORMAT:
            raise ValueError(f"{path}: expected format {VIEWS_FORMAT!r}, got {data.get('format')!r}")
        data = data.get("views")
    if not isinstance(data, list) or not data:
        raise ValueError(f"{path}: expected a non-empty list of views")
    return [View.from_dict(d) for d in data]


def views_from_sequence(views: Sequence[View] | View) -> list[View]:
    """Normalise one view or a sequence of views to a non-empty list of View."""
    seq = [views] if isinstance(views, View) else list(views)
    if not seq or not all(isinstance(v, View) for v in seq):
        raise ValueError(f"views must be a View or a non-empty sequence of View, got {views!r}")
    return seq
