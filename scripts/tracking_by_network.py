"""The live tracker on a moving cine, pair by pair, with each U-Net given: how each pair was found
(from scratch, warm, re-acquired), its focal error against the true pose, and what the verdict said:
its reasons, and per view how far that view alone moves the focal point and the cost it gains by
it (docs/campaigns.md, "Why a better U-Net was refused").

The cine is that of ``tests/lab/test_receiver.py``: the 0.25 mm model on a phantom background
(seeds 4 and 5), each pose about 0.9 mm and 0.9 deg from the last, the two views of the default
bi-plane C-arm; the tracker is the receiver's (fast warm regions, no retries, seed 0, the 0.47 mm
model). Each U-Net also drives the conic orientation initialiser (with the shipped VGG19 as its
fallback).

Usage::

    git show 0a23117:data/models/unet_standard.safetensors > /tmp/candidate.safetensors
    git show 0a23117:data/models/unet_standard.json > /tmp/candidate.json
    python scripts/tracking_by_network.py --pairs 10 --weights /tmp/candidate.safetensors
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def moving_poses(n: int):
    """``n`` poses, each about 0.9 mm and 0.9 deg from the last (tests/lab/test_receiver.py's)."""
    from histostudy.geometry import transform_from_params
    from histostudy.transducer import pose_facing

    step = transform_from_params([0.01, -0.01, 0.005, 0.6, -0.5, 0.4])
    poses = [pose_facing()]
    for _ in range(n - 1):
        T = poses[-1].copy()
        T[:3, :3] = step[:3, :3] @ T[:3, :3]
        T[:3, 3] += step[:3, 3]
        poses.append(T)
    return poses


def cine_frames(n_pairs: int):
    """``(poses, pairs)``: :func:`moving_poses`' ``n_pairs`` poses and their frame pairs (images of the
    default bi-plane C-arm's two views), through DICOM XA as the receiver gets them
    (tests/lab/test_receiver.py's cine)."""
    import numpy as np

    from histostudy.imaging import (
        default_biplane,
        detector_counts,
        load_frame,
        random_background,
        render_frame,
        write_xa,
    )
    from histostudy.transducer import TransducerModel

    views = default_biplane()
    poses = moving_poses(n_pairs)
    folder = Path(tempfile.mkdtemp(prefix="tracking-by-network-"))
    render_model = TransducerModel.build(spacing_mm=0.25)
    scene = random_background(np.random.default_rng(4), "phantom")
    rng = np.random.default_rng(5)
    paths = {}
    for view in views:
        counts = np.stack([detector_counts(render_frame(render_model, T, view, rng=rng, background=scene).image)
                           for T in poses])
        paths[view.name] = write_xa(folder / f"{view.name}.dcm", view, counts, frame_time_ms=66.7, uid_seed="cine")
    pairs = [[load_frame(paths[v.name], v, line_integrals=False, frame_index=i).image for v in views]
             for i in range(n_pairs)]
    return poses, pairs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=10, help="frame pairs of the cine (default 10)")
    parser.add_argument("--weights", action="append", default=[],
                        help="a U-Net checkpoint to track with besides the shipped one (repeatable)")
    args = parser.parse_args(argv)

    import numpy as np

    from histostudy.core import machine_summary
    from histostudy.imaging import default_biplane
    from histostudy.learning import UNetRunner, default_segmenter, default_vgg19
    from histostudy.pose import ConicOrientation, Tracker, TrackingConfig
    from histostudy.transducer import TransducerModel

    print(machine_summary())
    views = default_biplane()
    poses, frames = cine_frames(args.pairs)

    model = TransducerModel.build(spacing_mm=0.47)
    networks = {"shipped": default_segmenter()}
    networks.update({Path(w).name: UNetRunner.load(w) for w in args.weights})
    summary = []
    for name, unet in networks.items():
        orientation = ConicOrientation(segmenter=unet, fallback=default_vgg19())
        tracker = Tracker(model, views, segmenter=unet, orientation=orientation, rng=0,
                          fast=TrackingConfig(scratch_full_frames=False), mode="fast", retry_hypotheses=False)
        print(f"\n{name} (sha256 {unet.manifest['sha256'][:12]})")
        errors, refused = [], 0
        for i, pair in enumerate(frames):
            result = tracker.update(pair)
            error = float(np.linalg.norm(result.T_carm_transducer[:3, 3] - poses[i][:3, 3]))
            errors.append(error)
            refused += not result.verdict.ok
            v = result.verdict
            reasons = "; ".join(v.reasons) or "accepted"
            evidence = ", ".join(f"{view}: moves {v.view_disagreement_mm[view]:.2f} mm for "
                                 f"{v.view_gain_px2[view]:.3f} px² ({100 * v.view_relative_gain[view]:.1f}%)"
                                 for view in v.view_disagreement_mm)
            print(f"  pair {i}: {tracker.last_kind:13s} focal error {error:.3f} mm  {reasons}"
                  + (f"\n          single views: {evidence}" if evidence else ""))
        summary.append({"U-Net": name, "mean focal error (mm)": np.mean(errors), "max (mm)": np.max(errors),
                        "refused": refused, "warm": tracker.n_warm, "from scratch": tracker.n_from_scratch,
                        "lost": tracker.n_lost})
    import pandas as pd

    print("\n" + pd.DataFrame(summary).to_markdown(index=False, floatfmt=".3f"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
