"""The values Wagner et al. (IEEE TBME 2023) report, as data (:data:`PAPER`): what every reproduced
number is set beside, with the paper's own rounding, unit (percent, mm, degrees) and the place it
comes from (docs/report.md, "The paper's results and their twins")."""

from __future__ import annotations

from dataclasses import KW_ONLY, dataclass

__all__ = ["PAPER", "PaperValue", "paper_value"]


@dataclass(frozen=True)
class PaperValue:
    """One number the paper reports.

    Args:
        mean: the value as printed (a number, or text such as ``"< 1e-5"`` or an interval).
        sd: its standard deviation where the paper gives one (same unit), else None.
        unit: ``"%"``, ``"mm"``, ``"deg"``, ``"px"`` or ``""``.
        where: the place in the paper (``"Table II"``, ``"§III"``), cited by the report.
        label: its name for a reader (``"screws precision"``).
        twin: the key of the value that reports the same quantity elsewhere in the paper (§III's pose
            paragraph -> Table II), whose reproduction stands for this one too; ``""`` for none.
        needs: ``(key, why)``: the reproduced value this one cannot be computed without, and the
            reason, shown when a run lacks it; None for none.
    """

    mean: float | str
    sd: float | None = None
    unit: str = ""
    where: str = ""
    _: KW_ONLY
    label: str = ""
    twin: str = ""
    needs: tuple[str, str] | None = None

    def format(self, digits: int | None = None) -> str:
        """The value as the report prints it: ``"1.38 ± 0.54 mm"``.

        Args:
            digits: decimals; None prints each number in its shortest form (``:g``).

        Returns:
            The text (a text ``mean`` unchanged).
        """
        if isinstance(self.mean, str):
            return self.mean
        fmt = (lambda x: f"{x:.{digits}f}") if digits is not None else (lambda x: f"{x:g}")
        text = fmt(self.mean) if self.sd is None else f"{fmt(self.mean)} ± {fmt(self.sd)}"
        return f"{text} {self.unit}".strip()


_METRIC_NAMES = {"precision": "precision", "recall": "recall", "iou": "IoU", "accuracy": "accuracy"}
_TABLE2_ROWS = {"center_bias": "centre bias", "center_mae": "centre MAE", "margin_mae": "margin MAE",
                "radius_mae": "radius MAE"}
_DIRECTIONS = {"depth": "depth", "tb": "TB", "lr": "LR", "overall": "overall"}


def _table1() -> dict[str, PaperValue]:
    rows = {
        "background": ((92.3, 3.2), (99.8, 0.4), (92.1, 3.1), (95.0, 1.7)),
        "transducer": ((96.2, 1.7), (89.2, 4.1), (86.1, 3.5), (95.1, 1.6)),
        "outer_boundary": ((93.0, 8.0), (48.6, 4.6), (47.0, 5.6), (98.8, 0.4)),
        "inner_boundary": ((97.6, 3.0), (41.2, 5.0), (40.8, 4.9), (99.4, 0.2)),
        "gaps": ((90.4, 11.9), (59.9, 5.7), (56.5, 8.0), (99.6, 0.1)),
        "screws": ((82.2, 14.5), (68.4, 10.3), (59.1, 11.5), (99.2, 0.4)),
    }
    out = {}
    for cls, values in rows.items():
        for metric, (m, s) in zip(("precision", "recall", "iou", "accuracy"), values):
            out[f"table1.{cls}.{metric}"] = PaperValue(
                m, s, "%", "Table I", label=f"{cls.replace('_', ' ')} {_METRIC_NAMES[metric]}")
    return out


def _table2() -> dict[str, PaperValue]:
    rows = {
        "center_bias": ((0.0, 0.9), (0.3, 0.6), (-0.8, 0.6), None),
        "center_mae": ((0.7, 0.6), (0.5, 0.4), (0.8, 0.6), (1.4, 0.5)),
        "margin_mae": ((0.8, 0.5), (0.9, 0.7), (1.4, 0.7), (1.0, 0.7)),
        "radius_mae": ((0.3, 0.4), (0.6, 0.4), (0.6, 0.6), (0.5, 0.5)),
    }
    out = {}
    for row, values in rows.items():
        for direction, v in zip(("depth", "tb", "lr", "overall"), values):
            if v is not None:
                out[f"table2.{row}.{direction}"] = PaperValue(
                    v[0], v[1], "mm", "Table II", label=f"{_TABLE2_ROWS[row]}, {_DIRECTIONS[direction]}")
    return out


#: Every value the paper reports that the study reproduces or uses, by dotted key
#: (``"table1.<class>.<metric>"``, ``"table2.<row>.<direction>"``, ``"seg.*"``, ``"pose.*"``, ...).
PAPER: dict[str, PaperValue] = {
    # §II-B.1 digital model and §II-B.2 rendering, §II-D set-up.
    "model.radius_mm": PaperValue(138.7, None, "mm", "§II-B.1", label="cap sphere radius"),
    "model.cutout_diameter_mm": PaperValue(64.0, None, "mm", "§II-B.1", label="central cutout diameter"),
    "model.aperture_mm": PaperValue("≈ 240 x 170 mm", None, "", "§II-D", label="aperture, LR x TB"),
    "model.spacing_pose_mm": PaperValue(0.47, None, "mm", "§II-B.1", label="grid spacing, pose-estimation model"),
    "model.spacing_render_mm": PaperValue(0.125, None, "mm", "§II-B.1", label="grid spacing, rendering model"),
    "model.n_feature_classes": PaperValue(5, None, "", "§II-B.1", label="feature classes"),
    "render.n_splats": PaperValue(16, None, "", "§II-B.2", label="splats per point"),
    "render.splat_sigma_mm": PaperValue(0.5, None, "mm", "§II-B.2", label="splat offset SD"),
    "carm.gantry_angles_deg": PaperValue("−45° and +45° around PA", None, "", "§II-D", label="gantry angles"),
    "carm.network_input_px": PaperValue("310 x 240", None, "px", "§II-B.4", label="network input size"),
    "transducer.focal_length_mm": PaperValue(140.0, None, "mm", "§II-D", label="focal length"),
    "transducer.f_number": PaperValue(0.7, None, "", "§II-D", label="f-number"),
    # §III segmentation (Table I and text).
    **_table1(),
    "seg.global_accuracy": PaperValue(93.6, 1.9, "%", "§III", label="global accuracy"),
    "seg.weighted_iou": PaperValue(89.0, 3.21, "%", "§III", label="weighted IoU"),
    "seg.mean_precision": PaperValue(95.6, 2.2, "%", "§III", label="mean precision"),
    "seg.mean_recall": PaperValue(84.3, 3.3, "%", "§III", label="mean recall"),
    "seg.anova_F": PaperValue(85.6, None, "", "§III, F(5, 1262)", label="ANOVA F of precision over classes"),
    "seg.anova_df_between": PaperValue(5, None, "", "§III", label="ANOVA degrees of freedom, between"),
    "seg.anova_df_within": PaperValue(1262, None, "", "§III", label="ANOVA degrees of freedom, within"),
    "seg.anova_p": PaperValue("< 1e-5", None, "", "§III", label="ANOVA p"),
    "seg.tukey_screws_vs_background_ci": PaperValue(
        "[7.7, 10.1]", None, "%", "§III", label="Tukey 95 % CI, background minus screws precision",
        needs=("table1.screws.precision", "Tukey's test takes a class only where its precision is defined in two "
               "or more frames, that is where the U-Net predicted screws in them")),
    "seg.n_images": PaperValue(310, None, "", "§II-E.1", label="evaluation images"),
    # §III orientation regression.
    "angles.azimuth.pearson": PaperValue(99.1, None, "%", "§III", label="azimuth Pearson correlation"),
    "angles.elevation.pearson": PaperValue(99.9, None, "%", "§III", label="elevation Pearson correlation"),
    "angles.azimuth.slope": PaperValue(1.078, None, "", "§III", label="azimuth slope"),
    "angles.elevation.slope": PaperValue(1.048, None, "", "§III", label="elevation slope"),
    "angles.azimuth.intercept": PaperValue(-0.136, None, "deg", "§III", label="azimuth intercept"),
    "angles.elevation.intercept": PaperValue(-0.101, None, "deg", "§III", label="elevation intercept"),
    "angles.azimuth.r2": PaperValue(0.983, None, "", "§III", label="azimuth R²"),
    "angles.elevation.r2": PaperValue(0.999, None, "", "§III", label="elevation R²"),
    "angles.azimuth.mae": PaperValue(1.06, 0.71, "deg", "§III", label="azimuth MAE"),
    "angles.elevation.mae": PaperValue(2.34, 2.20, "deg", "§III", label="elevation MAE"),
    # §III pose estimation (text and Table II).
    **_table2(),
    "pose.center_euclidean": PaperValue(
        1.38, 0.54, "mm", "§III", label="centre error, Euclidean", twin="table2.center_mae.overall"),
    "pose.center_mae.depth": PaperValue(
        0.69, 0.58, "mm", "§III", label="centre MAE, depth", twin="table2.center_mae.depth"),
    "pose.center_mae.tb": PaperValue(0.52, 0.40, "mm", "§III", label="centre MAE, TB", twin="table2.center_mae.tb"),
    "pose.center_mae.lr": PaperValue(0.81, 0.56, "mm", "§III", label="centre MAE, LR", twin="table2.center_mae.lr"),
    "pose.center_bias.depth": PaperValue(
        0.01, None, "mm", "§III", label="centre bias, depth", twin="table2.center_bias.depth"),
    "pose.center_bias.tb": PaperValue(0.30, None, "mm", "§III", label="centre bias, TB", twin="table2.center_bias.tb"),
    "pose.center_bias.lr": PaperValue(
        -0.77, None, "mm", "§III", label="centre bias, LR", twin="table2.center_bias.lr"),
    "pose.margin_distance": PaperValue(
        1.04, 0.22, "mm", "§III", label="margin points to the treated zone's boundary",
        twin="table2.margin_mae.overall"),
    "pose.radius_mae": PaperValue(0.51, 0.24, "mm", "§III", label="radius MAE", twin="table2.radius_mae.overall"),
    "pose.n_studies": PaperValue(10, None, "", "§III", label="pose-estimation studies"),
    # §III automated targeting.
    "targeting.euclidean": PaperValue(
        1.64, 0.34, "mm", "§III, abstract 1.4 ± 0.5", label="targeting error, Euclidean"),
    "targeting.mae.depth": PaperValue(0.83, 0.65, "mm", "§III", label="targeting MAE, depth"),
    "targeting.mae.tb": PaperValue(0.46, 0.29, "mm", "§III", label="targeting MAE, TB"),
    "targeting.mae.lr": PaperValue(1.05, 0.58, "mm", "§III", label="targeting MAE, LR"),
    "targeting.bias.depth": PaperValue(-0.31, None, "mm", "§III", label="targeting bias, depth"),
    "targeting.bias.tb": PaperValue(0.11, None, "mm", "§III", label="targeting bias, TB"),
    "targeting.bias.lr": PaperValue(-1.01, None, "mm", "§III", label="targeting bias, LR"),
    "targeting.radius_mae": PaperValue(0.5, 0.5, "mm", "abstract", label="treated-zone radius MAE"),
    "targeting.n_studies": PaperValue(6, None, "", "§III", label="targeting studies"),
    "robot.repeatability_mm": PaperValue(0.03, None, "mm", "§II-C", label="UR5e repeatability"),
}


def paper_value(key: str) -> PaperValue:
    """The paper's value for ``key``.

    Args:
        key: a key of :data:`PAPER` (``"table2.center_mae.overall"``).

    Returns:
        Its :class:`PaperValue`.

    Raises:
        KeyError: ``key`` is unknown (the message lists known keys with its prefix).
    """
    try:
        return PAPER[key]
    except KeyError:
        prefix = key.split(".")[0]
        near = sorted(k for k in PAPER if k.startswith(prefix))[:12]
        raise KeyError(f"no paper value {key!r}; known keys with prefix {prefix!r}: {near}") from None
