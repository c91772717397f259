"""The U-Nets trained for tracking against the shipped U-Net (§II-B.2 Table I; docs/tracking.md, "A
network trained for tracking"): labels on held-out frames, and inference time on a tracking region.

Baseline, in the same run: the shipped ``data/models/unet_standard`` (input scale 0.5). Against it,
``--networks`` (names in ``data/models`` or checkpoint paths; default ``unet_tracking`` and, where
present, ``unet_tracking_fine``): ``unet_tracking`` is the same 8...128-channel U-Net at input scale
0.25, started from the shipped weights (``histostudy train segmentation_tracking``);
``unet_tracking_fine`` reads 0.5 and runs its levels at 0.25 (``input_stride=2``, ``histostudy train
segmentation_tracking_fine``).

Frames: the first ``--images`` (30) of the evaluation split (split ``eval``, seed of the standard
profile, which no training or validation frame shares) with notebook 02's standard rendering (the
0.125 mm physical model, mixed backgrounds, 50 000 photons per pixel), rendered into the frame cache
with ``--workers`` processes when missing.

Prints, per network:

- Table I (per class mean precision, recall and IoU in %, over the images where defined) of its
  full-resolution labels (``UNetRunner.segment``: logits upsampled to 960 x 1240) against the
  reference labels, and the global accuracy;
- the agreement of each tracking network's labels with the shipped one's: at full resolution, and
  on the grid the tracker uses (its arg-max at its input scale against the shipped 0.5 labels, pooled
  to that scale by overlap priority where it is coarser, :func:`~histostudy.learning.pool_labels`),
  over all pixels and over the pixels either network calls foreground;
- the median ms of ``UNetRunner.segment_region`` on a 448 x 448 frame-pixel tracking region
  (``--precision``, default ``auto``: bfloat16 on a CPU with native bfloat16) over ``--repeats``
  interleaved calls, and the ratio to the baseline. Torch runs on ``--threads`` (2) threads; the
  load average before and after says how busy the machine was.

Run: ``python benchmarks/bench_tracking_unet.py [--images 30] [--workers 2]``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from histostudy.learning import MODELS_DIR, UNetRunner, default_segmenter, pool_labels
from histostudy.reporting import load_profile
from histostudy.study.held_out import held_out_frames
from histostudy.study.segmentation import evaluate_segmentation, table1

BOX = (256, 704, 384, 832)  # 448 x 448 frame pixels, corners on the 64 px stride of the 0.25 network


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=30)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--precision", default="auto")
    parser.add_argument("--networks", nargs="+", default=None, metavar="NAME_OR_PATH",
                        help="tracking U-Nets: names in data/models or checkpoint paths (default: unet_tracking and, "
                             "where present, unet_tracking_fine)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    profile = load_profile("standard")
    common, nb = profile.common, profile.notebooks["02_segmentation"]
    fine = (MODELS_DIR / "unet_tracking_fine.safetensors").exists()
    names = args.networks or ["unet_tracking"] + (["unet_tracking_fine"] if fine else [])
    networks = {"shipped (0.5)": default_segmenter()}
    if networks["shipped (0.5)"] is None:
        raise SystemExit("the shipped U-Net (data/models/unet_standard) is missing or fails its check")
    for name in names:
        path = name if name.endswith(".safetensors") else MODELS_DIR / f"{name}.safetensors"
        net = UNetRunner.load(path)  # a ValueError names a missing or damaged file
        label = os.path.basename(str(name)).removesuffix(".safetensors").removeprefix("unet_")
        networks[f"{label[:18]} ({net.scale:g})"] = net
    t0 = time.perf_counter()
    frames = held_out_frames(profile.seed, args.images, render_spacing_mm=nb["render_spacing_mm"],
                             photons_per_pixel=common["photons_per_pixel"], n_splats=common["n_splats"],
                             splat_sigma_mm=common["splat_sigma_mm"], background=nb["background"],
                             render_workers=args.workers)
    frame_list = [frames.frame(i) for i in range(args.images)]
    print(f"{args.images} held-out frames (split 'eval', seed {profile.seed}, {nb['render_spacing_mm']} mm, "
          f"{nb['background']}) ready in {time.perf_counter() - t0:.0f} s; load average before: "
          f"{os.getloadavg()[0]:.2f}")

    tables, accuracy, full_labels = {}, {}, {}
    for name, net in networks.items():
        per_class, per_image, _ = evaluate_segmentation(net, frame_list, keep=0)
        tables[name] = table1(per_class).set_index("class")
        accuracy[name] = per_image["global_accuracy"].mean()
        full_labels[name] = [net.segment(f) for f in frame_list]
    print("\nTable I against the reference labels (mean % over images; full-resolution labels)")
    print(f"{'class':16s}" + "".join(f"{n + ' ' + m:>26s}" for n in networks for m in ("P/R/IoU",)))
    for cls in tables["shipped (0.5)"].index:
        row = f"{cls:16s}"
        for name in networks:
            t = tables[name].loc[cls]
            row += f"{t['precision_mean']:12.1f}{t['recall_mean']:7.1f}{t['iou_mean']:7.1f}"
        print(row)
    print(f"{'global accuracy':16s}" + "".join(f"{accuracy[n]:26.2f}" for n in networks))

    shipped = networks["shipped (0.5)"]
    fast = {name: net.with_precision(args.precision) for name, net in networks.items()}
    shipped_grid = [shipped.with_precision("float32").segment_region(f, (0, f.shape[0], 0, f.shape[1]))
                    for f in frame_list]
    for name, tracking in list(networks.items())[1:]:
        agree_full, agree_full_fg, agree_grid, agree_grid_fg = [], [], [], []
        for i, f in enumerate(frame_list):
            a, b = full_labels[name][i], full_labels["shipped (0.5)"][i]
            fg = (a > 0) | (b > 0)
            agree_full.append(np.mean(a == b))
            agree_full_fg.append(np.mean(a[fg] == b[fg]))
            rows, cols = f.shape
            grid = tracking.with_precision("float32").segment_region(f, (0, rows, 0, cols))
            ref = (shipped_grid[i] if tracking.scale == shipped.scale
                   else pool_labels(shipped_grid[i], tracking.scale / shipped.scale))
            fg = (grid > 0) | (ref > 0)
            agree_grid.append(np.mean(grid == ref))
            agree_grid_fg.append(np.mean(grid[fg] == ref[fg]))
        print(f"\nagreement of {name}'s labels with the shipped network's (mean over images, min)")
        for label, values in (("full resolution, all pixels", agree_full),
                              ("full resolution, foreground", agree_full_fg),
                              (f"{tracking.scale:g} grid, all pixels", agree_grid),
                              (f"{tracking.scale:g} grid, foreground", agree_grid_fg)):
            print(f"  {label:30s} {100 * np.mean(values):6.2f} %  (min {100 * np.min(values):.2f} %)")

    times = {name: [] for name in fast}
    frame = frame_list[0]
    for f in fast.values():
        f.segment_region(frame, BOX)  # warm-up: torch's convolution primitives
    for _ in range(args.repeats):
        for name, f in fast.items():
            t = time.perf_counter()
            f.segment_region(frame, BOX)
            times[name].append(time.perf_counter() - t)
    base = np.median(times["shipped (0.5)"])
    print(f"\nUNetRunner.segment_region on a {BOX[1] - BOX[0]} x {BOX[3] - BOX[2]} px region, precision "
          f"{fast['shipped (0.5)'].precision!r}, {args.threads} threads: median ms (min), x baseline")
    for name, values in times.items():
        print(f"  {name:16s} {1e3 * np.median(values):7.1f} ({1e3 * np.min(values):.1f})  "
              f"{base / np.median(values):5.2f}x")
    print(f"load average after: {os.getloadavg()[0]:.2f} (on {os.cpu_count()} cores)")


if __name__ == "__main__":
    t_start = time.perf_counter()
    main()
    print(f"(benchmark wall time {time.perf_counter() - t_start:.0f} s)")
