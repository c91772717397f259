"""The frames of the lab's chain in one picture (docs/your-data.md, "Frames and coordinates"): the
C-arm frame, which is the CBCT's world frame (DICOM LPS, mm), with RAS beside it as nibabel and 3D
Slicer show it; the CBCT's box; the two X-ray sources; the robot base, the flange and the
transducer of one calibration station; and the transducer's half turn about its axis.

Drawn from a generated lab dataset (``histostudy lab-dataset``): its ``truth.json``
(``T_carm_base``, ``T_flange_transducer``), ``calibration/flange_poses.json`` (``T_base_flange``),
``views.json`` (the sources) and ``cbct.nii.gz`` (the box). Every position is plotted in the C-arm
frame, LPS mm, with anterior (-y) up: the patient lies supine, the transducer above.

Usage::

    python scripts/figure_frames.py [DATASET] [--station 0] [--output docs/img/frames.png]

Without DATASET a dataset is generated in a temporary folder first.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

#: Colours of the x, y and z axes of every frame drawn.
AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def load_chain(folder: Path, station: int) -> dict:
    """The dataset's frames as 4x4 transforms into the C-arm frame (LPS mm), its sources and box."""
    from histostudy.imaging import load_views, load_volume
    from histostudy.lab import load_flange_poses

    truth = json.loads((folder / "truth.json").read_text())
    T_carm_base = np.asarray(truth["T_carm_base"], dtype=float)
    flanges = load_flange_poses(folder / "calibration" / "flange_poses.json")
    if not 0 <= station < len(flanges):
        raise SystemExit(f"--station {station}: the dataset has stations 0 to {len(flanges) - 1}")
    T_carm_flange = T_carm_base @ flanges[station]
    volume = load_volume(folder / "cbct.nii.gz")
    return {"T_carm_base": T_carm_base, "T_carm_flange": T_carm_flange,
            "T_carm_transducer": T_carm_flange @ np.asarray(truth["T_flange_transducer"], dtype=float),
            "sources": {v.name: v.source_mm for v in load_views(folder / "views.json")},
            "box": (volume.lower_mm, volume.upper_mm), "T_world_file_voxel": volume.T_world_file_voxel}


def draw_axes(ax, T, length, label, *, names=("x", "y", "z"), style="-", width=2.0, label_offset=(0, 0, 0)):
    """Three arrows of ``length`` mm along the columns of ``T[:3, :3]`` from ``T[:3, 3]``, labelled."""
    origin = T[:3, 3]
    for axis, (colour, name) in enumerate(zip(AXIS_COLOURS, names)):
        tip = origin + length * T[:3, axis]
        ax.plot(*np.c_[origin, tip], style, color=colour, lw=width)
        if name:
            ax.text(*(origin + 1.15 * length * T[:3, axis]), name, color=colour, fontsize=7)
    if label:
        ax.text(*(origin + np.asarray(label_offset)), label, fontsize=8, weight="bold")


def draw_box(ax, lower, upper, **style):
    """The 12 edges of the axis-aligned box ``[lower, upper]`` (mm)."""
    corners = np.array([[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1])
                        for z in (lower[2], upper[2])])
    for i in range(8):
        for j in range(i + 1, 8):
            if np.sum(corners[i] != corners[j]) == 1:
                ax.plot(*corners[[i, j]].T, **style)


def transducer_points(T_carm_transducer, step: int = 40) -> np.ndarray:
    """A sparse sample of the transducer's digital model, placed by ``T_carm_transducer`` (mm)."""
    from histostudy.transducer import Feature, TransducerModel

    points = TransducerModel.build(spacing_mm=1.0).points[Feature.TRANSDUCER][::step]
    return points @ T_carm_transducer[:3, :3].T + T_carm_transducer[:3, 3]


def _frame_view(ax, lower_mm, upper_mm) -> None:
    lower_mm, upper_mm = np.asarray(lower_mm, dtype=float), np.asarray(upper_mm, dtype=float)
    for setter, lo, hi in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), lower_mm, upper_mm):
        setter(lo, hi)
    ax.set_box_aspect(upper_mm - lower_mm)  # true proportions: a millimetre is a millimetre on every axis
    # seen from the patient's feet (the patient's left on the right, as radiology shows an axial
    # slice), from a little above and to the side; anterior (-y) up
    ax.view_init(elev=12, azim=10, vertical_axis="y")
    ax.set_proj_type("ortho")  # no perspective: depth does not shift a frame up or down
    ax.invert_yaxis()
    ax.set_xlabel("x mm (L)", fontsize=8)
    ax.set_ylabel("y mm (P)", fontsize=8)
    ax.set_zlabel("z mm (S)", fontsize=8)
    ax.tick_params(labelsize=6)


def draw_setup(ax, chain: dict) -> str:
    """The whole chain: C-arm frame and sources, CBCT box, base, flange, transducer; returns its key."""
    ax.scatter(*transducer_points(chain["T_carm_transducer"]).T, s=0.2, color="0.75", alpha=0.4)
    shown = [np.zeros(3), chain["T_carm_base"][:3, 3], chain["T_carm_flange"][:3, 3]]
    for name, source in chain["sources"].items():
        # the sources lie 785 mm off: drawn as the central ray's first 350 mm from the isocentre
        toward = 300.0 * source / np.linalg.norm(source)
        ax.plot(*np.c_[toward, np.zeros(3)], ":", color="0.3", lw=1.2)
        ax.text(*toward, f"to X-ray source {name}\n({np.linalg.norm(source):.0f} mm)", fontsize=7,
                ha="right" if source[0] < 0 else "left", va="top")
        shown.append(toward)
    draw_box(ax, *chain["box"], color="tab:purple", lw=1)
    draw_axes(ax, np.eye(4), 150, "C-arm = CBCT world\n(origin: isocentre)", names=("L", "P", "S"),
              label_offset=(40, 90, 0))
    draw_axes(ax, chain["T_carm_base"], 150, "robot base\nT_carm_base", label_offset=(-120, -190, 0))
    draw_axes(ax, chain["T_carm_flange"], 100, "flange\nT_carm_base @ T_base_flange", label_offset=(60, -90, 0))
    draw_axes(ax, chain["T_carm_transducer"], 100, "", names=("", "", ""))
    ax.text(*(chain["T_carm_transducer"][:3, 3] + [110, -110, 0]), "transducer\nT_carm_transducer", fontsize=8,
            weight="bold")
    arm = np.c_[chain["T_carm_base"][:3, 3], chain["T_carm_flange"][:3, 3], chain["T_carm_transducer"][:3, 3]]
    ax.plot(*arm, "--", color="0.55", lw=1)
    shown = np.array(shown)
    _frame_view(ax, shown.min(axis=0) - 120, shown.max(axis=0) + 120)
    ax.set_title("the chain (robot arm dashed, transducer grey)", fontsize=9)
    return ("each frame's x, y, z: red, green, blue\n"
            "the C-arm frame's: L (the patient's left), P (posterior), S (superior)\n"
            "the patient lies supine: anterior (-y) is up; the X-ray sources lie below\n"
            "T_carm_transducer = T_carm_base @ T_base_flange @ T_flange_transducer")


def draw_focus(ax, chain: dict) -> str:
    """Around the CBCT: LPS and RAS at the isocentre, the box and its voxel (0, 0, 0), the
    transducer's frame and its half turn; returns its key."""
    from histostudy.transducer import HALF_TURN

    draw_axes(ax, np.eye(4), 34, "", names=("+x L", "+y P", "+z S"))
    draw_axes(ax, np.diag([-1.0, -1.0, 1.0, 1.0]), 34, "", names=("+x R", "+y A", ""), style=":", width=1.5)
    lower, upper = chain["box"]
    draw_box(ax, lower, upper, color="tab:purple", lw=1)
    T_file = chain["T_world_file_voxel"]
    corner = T_file[:3, 3]
    for axis, name in enumerate("ijk"):
        step = T_file[:3, axis] / np.linalg.norm(T_file[:3, axis])
        ax.plot(*np.c_[corner, corner + 14 * step], color="tab:purple", lw=2)
        ax.text(*(corner + 18 * step), name, color="tab:purple", fontsize=8)
    ax.text(*(corner + [0, 8, 0]), "voxel (0,0,0)", color="tab:purple", fontsize=7)
    T = chain["T_carm_transducer"]
    draw_axes(ax, T, 16, "", names=("x", "y", ""))
    turned = T.copy()
    turned[:3, :3] = T[:3, :3] @ HALF_TURN
    draw_axes(ax, turned, 16, "", names=("x'", "y'", ""), style="--", width=1.2)
    ax.plot(*np.c_[T[:3, 3], T[:3, 3] + 45 * T[:3, 2]], color="tab:blue", lw=2)
    ax.text(*(T[:3, 3] + 48 * T[:3, 2]), "beam axis z", color="tab:blue", fontsize=7)
    _frame_view(ax, lower - 8, upper + 8)
    ax.set_zticks([-30, 0, 30])
    ax.set_title("around the CBCT", fontsize=9)
    return ("solid: LPS, the C-arm frame (histostudy, DICOM)\n"
            "dotted: RAS (nibabel, 3D Slicer): x and y negated\n"
            "purple: the CBCT's voxel centres; i, j, k as nibabel indexes cbct.nii.gz\n"
            "at the focal point: the transducer's x, y and, dashed, its half turn\n"
            "about z: the same focal point and axis, no image tells them apart")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", default=None, help="a folder of `histostudy lab-dataset` "
                                                                 "(default: generate one in a temporary folder)")
    parser.add_argument("--station", type=int, default=3,
                        help="the calibration station drawn (default 3: in the generated dataset, its transducer's "
                             "x axis lies between the world's, so that the two readings stand apart)")
    parser.add_argument("--output", default=str(REPO / "docs" / "img" / "frames.png"), help="the PNG written")
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.dataset) if args.dataset else Path(tmp) / "lab"
        if args.dataset is None:
            from histostudy.study.your_data.lab_dataset import write_lab_dataset

            write_lab_dataset(folder, n_cine_frames=1)
        elif not (folder / "truth.json").is_file():
            raise SystemExit(f"dataset {str(folder)!r}: no truth.json; expected a folder of `histostudy lab-dataset`")
        chain = load_chain(folder, args.station)
    fig = plt.figure(figsize=(11, 6.2))
    for column, draw in enumerate((draw_setup, draw_focus)):
        key = draw(fig.add_subplot(1, 2, column + 1, projection="3d"), chain)
        fig.text(0.04 + 0.5 * column, 0.15, key, fontsize=7.5, va="top")
    fig.suptitle("Frames of the lab's chain: every position in the C-arm frame, DICOM LPS, mm; "
                 "T_<to>_<from> maps <from> coordinates into <to>", fontsize=10)
    fig.subplots_adjust(left=0.0, right=0.98, bottom=0.15, top=0.92, wspace=0.05)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=100, bbox_inches="tight", pad_inches=0.15)
    print(f"written {args.output} ({Path(args.output).stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
