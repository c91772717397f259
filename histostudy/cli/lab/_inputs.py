"""Options and inputs the lab's commands share: the frames' options, the calibration's bounds, the
transducer from its CAD meshes, ``x,y,z`` triples; and the checks of the frame files and meshes
that run before any pose work, naming the flag, the argument or the file."""

from __future__ import annotations

import argparse
from pathlib import Path

from histostudy.core import WORLD_FRAME

from ..console import positive_int

__all__ = ["FRAME_SUFFIXES", "MAX_PAIR_GAP_S", "WORLD_FRAME", "check_frames", "check_transducer",
           "estimate_from_files", "frame_options", "model_from_args", "positive_int", "residual_options", "triple"]

FRAME_SUFFIXES = (".dcm", ".dicom", ".npy", ".png", ".tif", ".tiff")
#: The default bound on the seconds between one pose's DICOM frames (``--max-pair-gap-s``).
MAX_PAIR_GAP_S = 10.0
_MESH_SUFFIXES = (".stl", ".ply", ".obj", ".vtp")


def triple(text: str) -> tuple[float, float, float]:
    """``x,y,z``: three finite numbers."""
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(abs(v) < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected three finite numbers x,y,z, got {text!r}")
    return values


def frame_options(parser) -> None:
    """How frame files are read: views, the cine's frame, line integrals, resampling, the seed, the
    transducer's meshes."""
    parser.add_argument("--views", default=None, help="views JSON file (histostudy.imaging.save_views): matched by "
                                                      "order, or by name = the frame file's stem")
    parser.add_argument("--frame-index", type=int, default=None, help="the frame of each multi-frame file (a cine)")
    parser.add_argument("--line-integrals", action="store_true",
                        help="the files hold line integrals already (default: intensities, converted with -log(I/I0))")
    parser.add_argument("--resample", action="store_true", help="resize frames of another size onto their view")
    parser.add_argument("--seed", type=int, default=0, help="seed of the estimate's random draws (default 0)")
    parser.add_argument("--max-pair-gap-s", type=float, default=MAX_PAIR_GAP_S,
                        help="the most seconds between the acquisition times of one pose's DICOM frames (default "
                             f"{MAX_PAIR_GAP_S:g}: a biplane pair is taken at once; a monoplane C-arm's second view "
                             "after turning the gantry, give more)")
    parser.add_argument("--transducer", default=None, metavar="DIR",
                        help="the transducer's CAD meshes, one file per feature class named after it (transducer.stl, "
                             "outer_boundary.stl, inner_boundary.stl, gaps.stl, screws.stl; mm, transducer frame); "
                             "default: the paper's digital model")


def residual_options(parser) -> None:
    """The calibration's bounds, checked by ``calibrate`` and again by ``target``."""
    parser.add_argument("--max-focal-residual-mm", type=float, default=2.0,
                        help="the calibration's bound on each station's focal-point residual (default 2 mm)")
    parser.add_argument("--max-rotation-residual-deg", type=float, default=1.0,
                        help="the calibration's bound on each station's rotation residual (default 1 deg)")


def model_from_args(args):
    """The transducer model of ``--transducer`` (None: the digital model), cached on ``args``:
    ``calibrate`` estimates several poses with it."""
    from histostudy.transducer import TransducerModel

    if args.transducer is None:
        return None
    if getattr(args, "_model", None) is None:
        folder = Path(args.transducer)
        if not folder.is_dir():
            raise FileNotFoundError(f"--transducer {str(folder)!r}: no such folder of meshes")
        meshes = {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in _MESH_SUFFIXES}
        if not meshes:
            raise ValueError(f"--transducer {str(folder)!r} holds no mesh files ({', '.join(_MESH_SUFFIXES)})")
        args._model = TransducerModel.from_meshes(meshes)
    return args._model


def estimate_from_files(frames, args):
    """The pose of one station's or one pair's frame files, with the frames' options of ``args``."""
    from histostudy.pose import pose_from_files

    return pose_from_files(frames, args.views, frame_index=args.frame_index, line_integrals=args.line_integrals,
                           resample=args.resample, seed=args.seed, model=model_from_args(args))


_DICOM_SUFFIXES = (".dcm", ".dicom", "")


def check_frames(frames, args, *, label: str = "FRAMES") -> str | None:
    """Every frame file read as far as its pixel data, before any pose work, by the rules the
    estimate reads it by (:func:`histostudy.pose.frames_from_files`): it exists and has a frame
    format; it has a view (``--views``'s, by order or by name = the file's stem, or a DICOM file's
    geometry tags); a DICOM file is one whole X-ray object
    (:func:`~histostudy.imaging.io.check_xray_object`); ``--frame-index`` picks a frame each file
    holds; each image has its view's size unless ``--resample``; and the files are one acquisition
    of the planes (none twice, one study, ``--max-pair-gap-s``). ``label`` starts the messages
    about one file (the argument that named it). Returns the files' StudyInstanceUID (None when
    none carries one). Raises ValueError (XRayObjectRejected among them) or OSError naming the
    flag, the argument or the file."""
    paths = [Path(p) for p in frames]
    for path in paths:
        if path.is_dir():
            raise IsADirectoryError(f"{label} {str(path)!r} is a folder, not a frame file")
        if not path.is_file():
            raise FileNotFoundError(f"{label} {str(path)!r}: no such file")
        if path.suffix.lower() not in FRAME_SUFFIXES + ("",):
            raise ValueError(f"{label} {str(path)!r}: not a frame file (expected {', '.join(FRAME_SUFFIXES)}, or "
                             "DICOM without a suffix)")
    if args.frame_index is not None and args.frame_index < 0:
        raise ValueError(f"--frame-index {args.frame_index}: expected a frame index >= 0")
    headers: dict = {}  # each DICOM file's data set, read once
    for path, view in zip(paths, _views_of(paths, args, label)):
        if path.suffix.lower() in _DICOM_SUFFIXES:
            headers[path] = ds = _dicom_read_checked(path, view, args)
            shape: tuple[int, ...] = (int(ds.Rows), int(ds.Columns))
            n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
        else:
            shape, n_frames = _image_shape(path, label)
        where = f"{label} {str(path)!r}"
        if n_frames > 1 and args.frame_index is None:
            raise ValueError(f"{where} holds {n_frames} frames (a cine): pick one with --frame-index")
        if args.frame_index is not None and args.frame_index >= n_frames:
            raise ValueError(f"--frame-index {args.frame_index}: {where} holds {n_frames} frame(s), "
                             f"0 to {n_frames - 1}")
        if view is not None and shape != tuple(view.shape) and not args.resample:
            raise ValueError(f"{where} holds a {shape[0]} x {shape[1]} image, its view {view.name!r} in --views "
                             f"expects {view.shape[0]} x {view.shape[1]}: give --resample to resize it onto the view")
    return _check_one_acquisition(paths, headers, args, label)  # after each file's own checks: those name it


def _check_one_acquisition(paths: list, headers: dict, args, label: str) -> str | None:
    """Refuses frame files that are not one acquisition of the planes: a file given twice (the same
    path or the same bytes), one DICOM instance twice, DICOM files of different studies
    (StudyInstanceUID), or taken further apart than ``--max-pair-gap-s``. ``headers``: the DICOM
    files' data sets. Returns their study's UID, or None."""
    import hashlib
    import math

    gap_limit = getattr(args, "max_pair_gap_s", MAX_PAIR_GAP_S)
    if not (isinstance(gap_limit, (int, float)) and math.isfinite(gap_limit) and gap_limit >= 0):
        raise ValueError(f"--max-pair-gap-s must be a finite number of seconds >= 0, got {gap_limit!r}")
    seen: dict = {}
    for path in paths:
        for key in (("path", path.resolve()), ("bytes", hashlib.blake2b(path.read_bytes()).hexdigest())):
            if key in seen:
                how = "the same file" if key[0] == "path" else "the same bytes"
                raise ValueError(f"{label} {str(path)!r} is {str(seen[key])!r} again ({how}): a pose needs one frame "
                                 "per plane")
            seen[key] = path
    instances: dict = {}
    for path, ds in headers.items():
        uid = str(getattr(ds, "SOPInstanceUID", "") or "")
        if uid and uid in instances:
            raise ValueError(f"{label} {str(path)!r} and {str(instances[uid])!r} are one X-ray object "
                             f"(SOPInstanceUID {uid}): a pose needs one frame per plane")
        instances[uid] = path
    studies = {p: str(getattr(ds, "StudyInstanceUID", "") or "") for p, ds in headers.items()}
    named = {p: s for p, s in studies.items() if s}
    if len(set(named.values())) > 1:
        listed = " and ".join(f"{str(p)!r} (study {s})" for p, s in named.items())
        raise ValueError(f"{label} {listed} are of different studies: not one acquisition of the planes")
    study = next(iter(named.values()), None)
    times = {}
    for path, ds in headers.items():
        try:
            from histostudy.lab.pairing import frame_times

            acquired, _ = frame_times(ds)
        except ValueError:  # no acquisition time: nothing to compare
            continue
        index = args.frame_index if args.frame_index is not None and args.frame_index < len(acquired) else 0
        times[path] = acquired[index]
    if len(times) > 1:
        first, last = min(times.values()), max(times.values())
        try:
            gap_s = (last - first).total_seconds()
        except TypeError:  # one time with a UTC offset, one without: not comparable
            return study
        if gap_s > gap_limit:
            listed = " and ".join(f"{str(p)!r} ({t.isoformat()})" for p, t in times.items())
            raise ValueError(f"{label} {listed} were taken {gap_s:g} s apart, more than --max-pair-gap-s "
                             f"{gap_limit:g}: not one acquisition of the planes (a biplane pair is taken at once)")
    return study


def _views_of(paths: list, args, label: str) -> list:
    """Each frame file's view from ``--views`` (:func:`histostudy.pose.match_views`, as the estimate
    matches them), or None for a DICOM file's own tags."""
    from histostudy.imaging import load_views
    from histostudy.pose import match_views

    if args.views is None:
        bare = [p for p in paths if p.suffix.lower() not in _DICOM_SUFFIXES]
        if bare:
            raise ValueError(f"{label} {str(bare[0])!r} carries no geometry (not DICOM): give the frames' views "
                             "with --views FILE")
        return [None] * len(paths)
    if not Path(args.views).is_file():
        raise FileNotFoundError(f"--views {args.views!r}: no such file")
    try:
        views = load_views(args.views)
    except (OSError, ValueError, TypeError, KeyError) as exc:  # load_views lets json's errors through unnamed
        raise ValueError(f"--views {args.views!r} is not a views file: {exc}") from None
    try:
        return match_views(views, paths)
    except ValueError as exc:
        raise ValueError(f"--views {args.views!r} {exc}") from None


def _dicom_read_checked(path: Path, view, args):
    """A DICOM frame file's data set, the file read whole and checked as the estimate checks it;
    its view from its tags too when ``view`` is None."""
    from histostudy.imaging import View
    from histostudy.imaging.io import XRayObjectRejected, check_xray_object, read_dicom_file

    ds = read_dicom_file(path)  # to its pixel data: a truncated or corrupt file is named here
    n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
    index = args.frame_index if args.frame_index is not None and args.frame_index < n_frames else None
    if view is None:
        try:
            View.from_dicom(path, frame_index=index, name=path.stem)  # its messages name the file
        except XRayObjectRejected:
            raise  # not an X-ray image: the same reason as every reader's
        except ValueError as exc:  # a geometry tag missing or out of range: a views file stands in
            text = str(exc)
            raise ValueError(text.replace("a views file", "a views file (--views FILE)") if "a views file" in text
                             else f"{text}; or give the frames' views with --views FILE") from None
    else:
        _check_views_against_tags(path, ds, view, index, args)
    check_xray_object(ds, source=f"path {str(path)!r}")
    return ds


def _check_views_against_tags(path: Path, ds, view, index: int | None, args) -> None:
    """Refuses a ``--views`` view whose geometry the file's own gantry tags contradict: projecting
    more than :data:`VIEW_MATCH_TOLERANCE_MM` apart (at the isocentre), as the live receiver
    refuses a plane whose tags are that far from its view. A file without readable tags is the
    views file's to describe."""
    from histostudy.imaging import View
    from histostudy.imaging.io import XRayObjectRejected
    from histostudy.lab import VIEW_MATCH_TOLERANCE_MM

    try:
        tags = View.from_dicom(ds, frame_index=index)
    except (ValueError, XRayObjectRejected):
        return
    if tags.shape != tuple(view.shape):
        return  # --resample's case, checked with the image size
    distance = tags.projection_distance_mm(view)
    if distance > VIEW_MATCH_TOLERANCE_MM:
        raise ValueError(f"--views {args.views!r}: view {view.name!r} and the gantry tags of {str(path)!r} project "
                         f"{distance:.1f} mm apart at the isocentre (> {VIEW_MATCH_TOLERANCE_MM:g} mm): the views "
                         "file was calibrated for another geometry, or the gantry moved since; give the views of "
                         "these frames, or leave --views out to read the tags")


def _image_shape(path: Path, label: str) -> tuple[tuple[int, ...], int]:
    """A .npy, .png or .tif frame file's image size and frame count (a .npy read as a memory map)."""
    import numpy as np

    try:
        if path.suffix.lower() == ".npy":
            shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
        else:
            import cv2

            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise ValueError("not a readable image")
            shape = image.shape[:2]
    except (OSError, ValueError) as exc:
        raise ValueError(f"{label} {str(path)!r} could not be read: {exc}") from None
    if len(shape) not in (2, 3):
        raise ValueError(f"{label} {str(path)!r} holds an array of shape {shape}, expected a (rows, cols) frame "
                         "or a (frames, rows, cols) stack")
    return tuple(shape[-2:]), (shape[0] if len(shape) == 3 else 1)


def check_transducer(args) -> None:
    """``--transducer``'s meshes loaded (:func:`model_from_args`, which keeps the model for the
    estimate), a failure named with the flag."""
    if args.transducer is None:
        return
    try:
        model_from_args(args)
    except (ValueError, TypeError, OSError) as exc:
        text = str(exc)
        named = text if text.startswith("--transducer") else f"--transducer {args.transducer!r}: {text}"
        raise (FileNotFoundError if isinstance(exc, FileNotFoundError) else ValueError)(named) from None
