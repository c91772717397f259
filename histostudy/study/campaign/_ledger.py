"""A campaign's ledger, ``data/campaigns/<name>/ledger.json``: one entry per step (where and how long
it ran, what it trained, what the held-out frames measured), appended atomically, and its table."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from histostudy.core import atomic_write_json, to_jsonable

__all__ = ["append_entry", "ledger_table", "read_ledger"]

FORMAT = "histostudy.campaign-ledger"


def read_ledger(path) -> list[dict]:
    """The entries of a campaign's ledger.

    Args:
        path: the ledger file (``data/campaigns/<name>/ledger.json``).

    Returns:
        Its runs, oldest first; an empty list where there is no ledger yet.

    Raises:
        ValueError: the file is not a campaign ledger (the message names it).
    """
    path = Path(path)
    if not path.is_file():
        return []
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"ledger {str(path)!r} is not readable JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("runs"), list):
        raise ValueError(f"ledger {str(path)!r} is not a {FORMAT} file (an object with 'format' and 'runs')")
    return data["runs"]


def append_entry(path, campaign: str, entry: dict) -> dict:
    """Add ``entry`` to the ledger at ``path`` as its next run (numbered from 1), atomically.

    Args:
        path: the ledger file (created with its first run).
        campaign: the campaign's name.
        entry: the run's record (JSON-able after :func:`~histostudy.core.to_jsonable`).

    Returns:
        The entry as written, with its ``run`` number.
    """
    runs = read_ledger(path)
    entry = to_jsonable({"run": len(runs) + 1, **entry})
    atomic_write_json(path, {"format": FORMAT, "campaign": campaign, "runs": [*runs, entry]})
    return entry


def ledger_table(runs: list[dict]) -> pd.DataFrame:
    """The ledger as a table.

    Args:
        runs: the ledger's runs (:func:`read_ledger`).

    Returns:
        One row per step: when, where (CPU or GPU), how it started, wall minutes, CPU-hours (this
        step's training and the campaign's to date), training steps to date, and the held-out
        figures (a U-Net's screws precision / recall / IoU and pixel accuracy, percent; a VGG19's
        azimuth and elevation MAE and median direction error, deg) with their seed and frames; where
        the step measured its baseline on the same frames, the baseline's figure beside it and the
        paired comparison (``*_median_diff``: the median per-frame difference, candidate - baseline;
        ``*_wins``: frames where the candidate is better, of ``n``; ``*_p``: Wilcoxon's two-sided p).
    """
    rows, total = [], 0.0
    for run in runs:
        total += float(run.get("cpu_hours", 0.0))
        held = run.get("held_out", {})
        row = {"run": run["run"], "date": str(run.get("finished_utc", ""))[:10],
               "device": run.get("machine", {}).get("device", ""), "start": run.get("start", ""),
               "wall_min": run.get("wall_minutes"), "cpu_h": run.get("cpu_hours"), "cpu_h_total": total,
               "steps": run.get("steps_after"), "train_frames": run.get("n_train"), "stopped": run.get("stopped", "")}
        baseline = run.get("baseline", {}).get("held_out", {})
        if "per_class" in held:
            screws = held["per_class"]["screws"]
            row.update(screws_precision=screws["precision"], screws_recall=screws["recall"],
                       screws_iou=screws["iou"], pixel_accuracy=held.get("global_accuracy"))
            if baseline:
                row.update(_paired_columns("screws_iou", baseline["per_class"]["screws"]["iou"],
                                           run["paired"]["screws"]))
        elif held:
            row.update(azimuth_mae_deg=held.get("azimuth_mae_deg"), elevation_mae_deg=held.get("elevation_mae_deg"),
                       direction_median_deg=held.get("direction_median_deg"))
            if baseline:
                row.update(_paired_columns("direction_deg", baseline["direction_median_deg"],
                                           run["paired"]["direction_error_deg"]))
        row.update(held_out_seed=held.get("seed"), held_out_frames=held.get("frames"))
        rows.append(row)
    return pd.DataFrame(rows)


def _paired_columns(figure: str, baseline_value, paired: dict) -> dict:
    return {f"baseline_{figure}": baseline_value, f"{figure}_median_diff": paired["median_difference"],
            f"{figure}_wins": f"{paired['wins']}/{paired['n']}", f"{figure}_p": paired["p_value"]}
