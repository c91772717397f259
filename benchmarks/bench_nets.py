"""Speed of the learned stages (§II-B.2, §II-B.4), each against a baseline measured in the same run.

Prints:
- U-Net inference per full 1240x960 frame with :class:`histostudy.learning.UNetRunner` (the
  shipped standard network, input downscaled by 0.5, logits upsampled to full size) against the
  same network run on the full-resolution frame (baseline), and the 0.5 s target;
- with ``--inference``: each precision of :class:`~histostudy.learning.UNetRunner` on a tracking
  region (896 x 768 frame pixels, 448 x 384 network pixels) and on a whole frame against
  ``"reference"`` (median and minimum ms of ``--repeat`` interleaved calls, and the labels' agreement),
  and the inference network's parts against their plain torch equivalents (the fused
  ``Conv2d -> ReLU``, the head with its arg-max in one pass); ``--isa avx2`` reruns it as on a CPU
  with AVX2 only (:func:`histostudy.core.run_restricted_to`), ``--inference-only`` skips the rest;
- VGG19 inference per view (one 310x240 input, :class:`histostudy.learning.orientation.LearnedOrientation`)
  for the shipped width-1/8 network against the full-width VGG19 (baseline);
- training steps per second at batch 5: the standard U-Net on 256x256 crops against the
  16...256-channel U-Net on the same crops (the configuration timed in the issue, baseline), and
  the width-1/8 VGG19 against the full-width VGG19 on 310x240 inputs (baseline).

Networks come from ``data/models`` when the shipped weights are there (the standard profile's
configuration otherwise, with random weights: the speed is the same). Times are the median of
``--repeat`` runs after one warm-up. Run: ``python benchmarks/bench_nets.py [--repeat 5] [--threads N]
[--inference [--inference-only] [--isa native|avx2]]`` (docs/inference.md has its figures).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch
from torch.nn import functional as F

from histostudy.core import BENCHMARK_ISAS, machine_summary, run_restricted_to
from histostudy.imaging import Frame, default_biplane
from histostudy.learning import LearnedOrientation, UNetRunner, build_network, shipped_model
from histostudy.learning.nets import VGG19, UNet
from histostudy.reporting import load_profile

#: The tracking region of ``--inference``: 896 x 768 frame pixels (448 x 384 at the network's 0.5).
REGION = (32, 928, 256, 1024)


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
        loader = UNetRunner if task == "segmentation" else LearnedOrientation
        return loader.load(path), f"shipped {path.name}"
    cfg = dict(load_profile("standard").training[task]["network"])
    if task == "segmentation":
        return UNetRunner(build_network(cfg).eval(), scale=0.5), f"standard config {cfg} (random weights)"
    net = build_network({**cfg, "head": "regressor"}).eval()
    return LearnedOrientation(net, scale=0.25), f"standard config {cfg} (random weights)"


def _train_step(net, x, target, loss_fn):
    opt = torch.optim.SGD(net.parameters(), lr=1e-3, momentum=0.9)

    def step():
        opt.zero_grad(set_to_none=True)
        loss_fn(net(x), target).backward()
        opt.step()
    return step


def _interleaved_ms(calls: dict, repeat: int) -> dict:
    """Median and minimum ms of each of ``calls`` (name -> function), called in turn ``repeat`` times
    after one warm-up each, so that a change of the machine's load falls on all of them alike."""
    times = {name: [] for name in calls}
    for fn in calls.values():
        fn()
    for _ in range(repeat):
        for name, fn in calls.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(1e3 * (time.perf_counter() - t0))
    return {name: (statistics.median(t), min(t)) for name, t in times.items()}


def _inference(seg: UNetRunner, frame: Frame, repeat: int) -> None:
    """Each precision of the runner against "reference", and the inference network's parts against
    plain torch (module docstring)."""
    import os

    from histostudy.learning import native_bfloat16

    precisions = ["reference", "float32"] + (["bfloat16"] if native_bfloat16() else [])
    runners = {p: seg.with_precision(p) for p in precisions}
    try:
        runners["int8"] = seg.with_precision("int8")
    except ValueError as exc:  # no int8 kernels in this torch, or no calibration of these weights
        print(f"  int8 left out: {exc}")

    def region(runner):
        def call():
            runner._recent.clear()  # a new frame each time: no features kept from the last call
            return runner.segment_region(frame, REGION)
        return call

    print(f"\nUNetRunner, {machine_summary()}, load {os.getloadavg()[0]:.1f}")
    print(f"  region {REGION} ({(REGION[1] - REGION[0]) // 2} x {(REGION[3] - REGION[2]) // 2} network pixels), "
          f"ms median / min of {repeat} interleaved calls; labels against 'reference'")
    on_region = _interleaved_ms({p: region(r) for p, r in runners.items()}, repeat)
    reference = runners["reference"].segment_region(frame, REGION)
    for p, (median, low) in on_region.items():
        agree = np.mean(runners[p].segment_region(frame, REGION) == reference)
        print(f"    {p:>9}: {median:7.1f} / {low:7.1f} ms   {100 * agree:.3f} % of the labels")
    def whole_frame(runner):
        def call():
            runner._recent.clear()
            return runner.segment(frame)
        return call

    whole = _interleaved_ms({p: whole_frame(r) for p, r in runners.items()}, max(1, repeat // 2))
    print(f"  whole frame (labels at 960 x 1240), ms median / min of {max(1, repeat // 2)}:")
    for p, (median, low) in whole.items():
        print(f"    {p:>9}: {median:7.1f} / {low:7.1f} ms")

    # the parts: Conv2d -> ReLU fused against the eager pair; the head and arg-max in one pass
    # against torch's head then arg-max (on the same kept features)
    from histostudy.learning.inference import runner as runner_module

    fuse, unfused = runner_module.fuse_conv_relu, {}
    runner_module.fuse_conv_relu = lambda net: (net, 0)
    try:
        for p in [p for p in ("float32", "bfloat16") if p in runners]:
            unfused[p] = seg.with_precision(p)
    finally:
        runner_module.fuse_conv_relu = fuse
    calls = {}
    for p, plain in unfused.items():
        calls[f"{p}, {runners[p].n_fused_layers} pairs fused"] = region(runners[p])
        calls[f"{p}, none fused"] = region(plain)
    parts = _interleaved_ms(calls, repeat)
    print("  the inference network's parts, region, ms median / min:")
    for name, (median, low) in parts.items():
        print(f"    {name:>28}: {median:7.1f} / {low:7.1f} ms")
    for p in [p for p in ("float32", "bfloat16") if p in runners]:
        r = runners[p]
        r.segment_region(frame, REGION)  # its features kept
        heads = _interleaved_ms({"one pass": lambda r=r: r._labels(frame, REGION),
                                 "torch head, arg-max": lambda r=r: r._logits(frame, REGION).argmax(dim=0).numpy()},
                                repeat)
        same = np.array_equal(r._labels(frame, REGION), r._logits(frame, REGION).argmax(dim=0).numpy())
        print(f"    {p} head and arg-max: one pass {heads['one pass'][0]:.2f} / {heads['one pass'][1]:.2f} ms, "
              f"torch {heads['torch head, arg-max'][0]:.2f} / {heads['torch head, arg-max'][1]:.2f} ms "
              f"(same labels: {same})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    parser.add_argument("--inference", action="store_true", help="also time each precision of UNetRunner")
    parser.add_argument("--inference-only", action="store_true", help="time UNetRunner's precisions only")
    parser.add_argument("--isa", choices=BENCHMARK_ISAS, default="native",
                        help="avx2: run as on a CPU with AVX2 only (the command again, its libraries restricted)")
    args = parser.parse_args()
    run_restricted_to(args.isa)
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, median of {args.repeat}")
    view = default_biplane()[0]
    rng = np.random.default_rng(0)
    frame = Frame(rng.normal(4.0, 1.0, view.shape).astype(np.float32), view)
    if args.inference or args.inference_only:
        seg, what = _standard_network("segmentation", "unet_standard")
        print(f"\nU-Net: {what}")
        _inference(seg, frame, args.repeat)
        if args.inference_only:
            return

    seg, what = _standard_network("segmentation", "unet_standard")
    t_seg = _median_time(lambda: seg.segment(frame), args.repeat)
    full = UNetRunner(seg.network, scale=1.0)
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
