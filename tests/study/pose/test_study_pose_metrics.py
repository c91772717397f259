"""Tests of histostudy.study.pose._metrics: Table II's arithmetic on records with known errors."""

import numpy as np
import pandas as pd
import pytest

from histostudy.study.pose.geometry import DIRECTIONS, MARGINS, margin_positions, transducer_axes
from histostudy.study.pose.metrics import experiment_metrics, table2
from histostudy.transducer import pose_facing

T_CENTRE = pose_facing((0.1, 1.0, -0.2), focal_point_mm=(3.0, -2.0, 5.0), axial_rotation_rad=0.4)


def synthetic_records(offsets: dict, radius: float = 10.0, experiment: int = 0) -> pd.DataFrame:
    """Records whose prediction = truth + offsets[position] (world mm), for one experiment."""
    rows = []
    for position, T in margin_positions(T_CENTRE, radius).items():
        truth = T[:3, 3]
        pred = truth + np.asarray(offsets.get(position, np.zeros(3)))
        axes = transducer_axes(T_CENTRE)
        err = pred - truth
        rows.append({"experiment": experiment, "radius_mm": radius, "position": position, "mode": "paper",
                     "maps": "occlusion_aware", **{f"true_{a}": v for a, v in zip("xyz", truth)},
                     **{f"pred_{a}": v for a, v in zip("xyz", pred)},
                     **{f"err_{d}": float(err @ axes[d]) for d in DIRECTIONS},
                     "err_euclidean": float(np.linalg.norm(err)), "ok": True})
    return pd.DataFrame(rows)


def test_table2_of_a_pure_shift_is_the_shift_in_the_centre_and_nothing_in_the_radius():
    axes = transducer_axes(T_CENTRE)
    shift = 0.3 * axes["depth"] - 0.4 * axes["lr"]
    records = synthetic_records({p: shift for p in ["centre", *MARGINS]})
    metrics = experiment_metrics(records)
    row = metrics.iloc[0]
    assert row["centre_err_depth"] == pytest.approx(0.3) and row["centre_err_lr"] == pytest.approx(-0.4)
    assert row["centre_err_tb"] == pytest.approx(0.0, abs=1e-12)
    assert row["centre_err_euclidean"] == pytest.approx(0.5)
    # Opposite margins shift together: the predicted radius is exact and the precision is zero.
    for d in DIRECTIONS:
        assert row[f"radius_err_{d}"] == pytest.approx(0.0, abs=1e-12)
    assert row["precision"] == pytest.approx(0.0, abs=1e-12)
    # Margin error: distance of each shifted margin point to the reference sphere's surface.
    top = np.linalg.norm(10.0 * axes["tb"] + shift) - 10.0
    assert row["margin_err_top"] == pytest.approx(abs(top))
    table, values = table2(metrics, "paper")
    assert values["table2.center_bias.depth"][0] == pytest.approx(0.3)
    assert values["table2.center_mae.lr"][0] == pytest.approx(0.4)
    assert values["table2.center_mae.overall"][0] == pytest.approx(0.5)
    assert list(table.columns) == ["", "Depth", "TB", "LR", "Overall"]
    assert table.loc[0, "Overall"] == "N/A"  # the paper has no overall bias either


def test_table2_of_a_radial_stretch_is_the_radius_error():
    axes = transducer_axes(T_CENTRE)
    offsets = {name: sign * 0.25 * axes[d] for name, (d, sign) in MARGINS.items()}
    metrics = experiment_metrics(synthetic_records(offsets, radius=12.5))
    row = metrics.iloc[0]
    for d in DIRECTIONS:
        assert row[f"radius_{d}"] == pytest.approx(12.75)
        assert row[f"radius_err_{d}"] == pytest.approx(0.25)
        assert row[f"margin_err_{d}"] == pytest.approx(0.25)
    assert row["centre_err_euclidean"] == 0.0 and row["precision"] == pytest.approx(0.0, abs=1e-12)


def test_table2_mean_and_sd_are_over_experiments():
    axes = transducer_axes(T_CENTRE)
    records = pd.concat([synthetic_records({"centre": b * axes["tb"]}, experiment=e)
                         for e, b in enumerate([0.2, -0.6, 1.0])])
    _, values = table2(experiment_metrics(records), "paper")
    mean, sd = values["table2.center_bias.tb"]
    assert mean == pytest.approx(np.mean([0.2, -0.6, 1.0])) and sd == pytest.approx(np.std([0.2, -0.6, 1.0], ddof=1))
    assert values["table2.center_mae.tb"][0] == pytest.approx(0.6)
    with pytest.raises(ValueError, match="no experiment metrics for mode='fast'"):
        table2(experiment_metrics(records), "fast")
