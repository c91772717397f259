"""Speed of the learned stages (§II-B.2, §II-B.4), each against a baseline measured in the same run.

Prints:
- U-Net inference per full 1240x960 frame with :class:`histostudy.learning.segment.UNetSegmenter` (the
  shipped standard network, input downscaled by 0.5, logits upsampled to full size) against the
  same network run on the full-resolution frame (baseline), and the 0.5 s target;
- VGG19 inference per view (one 310x240 input, :class:`histostudy.learning.orientation.LearnedOrientation`)
  for the shipped width-1/8 network against the full-width VGG19 (baseline);
- training steps per second at batch 5: the standard U-Net on 256x256 crops against the
  16...256-channel U-Net on the same crops (the configuration timed in the issue, baseline), and
  the width-1/8 VGG19 against the full-width VGG19 on 310x240 inputs (baseline).

Networks come from ``data/models`` when the shipped weights are there (the standard profile's
configuration otherwise, with random weights: the speed is the same). Times are the median of
``--repeat`` runs after one warm-up. Run: ``python benchmarks/bench_nets.py [--repeat 5] [--threads N]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch
from torch.nn import functional as F

from histostudy.imaging import Frame, default_biplane
from histostudy.learning import VGG19, LearnedOrientation, UNet, UNetSegmenter, build_network, shipped_model
from histostudy.reporting import load_profile


def _median_time(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _standard_network(task: str, name: str):
    path = shipped_model(name)
    if path is not None:
        loader = UNetSegmenter if task == "segmentation" else LearnedOrientation
        return loader.load(path), f"shipped {path.name}"
    cfg = dict(load_profile("standard").training[task]["network"])
    if task == "segmentation":
        return UNetSegmenter(build_network(cfg).eval(), scale=0.5), f"standard config {cfg} (random weights)"
    net = build_network({**cfg, "head": "regressor"}).eval()
    return LearnedOrientation(net, scale=0.25), f"standard config {cfg} (random weights)"


def _train_step(net, x, target, loss_fn):
    opt = torch.optim.SGD(net.parameters(), lr=1e-3, momentum=0.9)

    def step():
        opt.zero_grad(set_to_none=True)
        loss_fn(net(x), target).backward()
        opt.step()
    return step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, median of {args.repeat}")
    view = default_biplane()[0]
    rng = np.random.default_rng(0)
    frame = Frame(rng.normal(4.0, 1.0, view.shape).astype(np.float32), view)

    seg, what = _standard_network("segmentation", "unet_standard")
    t_seg = _median_time(lambda: seg.segment(frame), args.repeat)
    full = UNetSegmenter(seg.network, scale=1.0)
    t_full = _median_time(lambda: full.segment(frame), max(1, args.repeat // 2))
    print(f"\nU-Net inference per {view.shape[1]}x{view.shape[0]} frame ({what}):")
    print(f"  at input scale {seg.scale}: {t_seg:.3f} s   baseline, full resolution: {t_full:.3f} s   "
          f"ratio {t_full / t_seg:.1f}x   target <= 0.5 s: {'met' if t_seg <= 0.5 else 'missed'}")

    src, what = _standard_network("orientation", "vgg19_standard")
    t_vgg = _median_time(lambda: src.estimate(frame), args.repeat)
    big = LearnedOrientation(VGG19(width=1.0, head="regressor").eval(), scale=0.25)
    t_big = _median_time(lambda: big.estimate(frame), max(1, args.repeat // 2))
    print(f"\nVGG19 inference per view, 310x240 input ({what}):")
    print(f"  {t_vgg * 1e3:.1f} ms   baseline, full-width VGG19: {t_big * 1e3:.1f} ms   ratio {t_big / t_vgg:.1f}x")

    print("\nTraining steps per second, batch 5, SGD momentum 0.9:")
    torch.manual_seed(0)
    x, y = torch.randn(5, 1, 256, 256), torch.randint(0, 6, (5, 256, 256))
    cfg = dict(load_profile("standard").training["segmentation"]["network"])
    std_unet = _train_step(build_network(cfg).train(), x, y, F.cross_entropy)
    ref_unet = _train_step(UNet(base_width=16, depth=4).train(), x, y, F.cross_entropy)
    t_a, t_b = _median_time(std_unet, args.repeat), _median_time(ref_unet, max(1, args.repeat // 2))
    print(f"  U-Net {cfg}, 256x256: {1 / t_a:.2f} steps/s   baseline U-Net 16...256: {1 / t_b:.2f} steps/s   "
          f"ratio {t_b / t_a:.1f}x")
    xv, yv = torch.randn(5, 1, 240, 310), torch.rand(5, 2)
    vcfg = dict(load_profile("standard").training["orientation"]["network"])
    std_vgg = _train_step(build_network({**vcfg, "head": "regressor"}).train(), xv, yv, F.mse_loss)
    ref_vgg = _train_step(VGG19(width=1.0, head="regressor").train(), xv, yv, F.mse_loss)
    t_a, t_b = _median_time(std_vgg, args.repeat), _median_time(ref_vgg, 1)
    print(f"  VGG19 {vcfg}, 310x240: {1 / t_a:.2f} steps/s   baseline full-width VGG19: {1 / t_b:.3f} steps/s   "
          f"ratio {t_b / t_a:.1f}x")


if __name__ == "__main__":
    main()
