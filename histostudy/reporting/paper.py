"""The values Wagner et al. (IEEE TBME 2023) report, as data: what every reproduced figure is set beside.

Keys are dotted names used by the study notebooks when they record a comparison
(:meth:`histostudy.reporting.report.SectionWriter.compare`). Each value keeps the paper's own rounding and
the place it comes from, so the report can cite it. Percentages are in percent, lengths in mm,
angles in degrees, as printed in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PAPER", "PaperValue", "paper_value"]


@dataclass(frozen=True)
class PaperValue:
    """One reported number: ``mean`` (± ``sd`` where the paper gives one), its unit and source."""

    mean: float | str
    sd: float | None = None
    unit: str = ""
    where: str = ""

    def format(self, digits: int | None = None) -> str:
        if isinstance(self.mean, str):
            return self.mean
        fmt = (lambda x: f"{x:.{digits}f}") if digits is not None else (lambda x: f"{x:g}")
        text = fmt(self.mean) if self.sd is None else f"{fmt(self.mean)} ± {fmt(self.sd)}"
        return f"{text} {self.unit}".strip()


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
            out[f"table1.{cls}.{metric}"] = PaperValue(m, s, "%", "Table I")
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
                out[f"table2.{row}.{direction}"] = PaperValue(v[0], v[1], "mm", "Table II")
    return out


PAPER: dict[str, PaperValue] = {
    # §II-B.1 digital model and §II-B.2 rendering, §II-D set-up.
    "model.radius_mm": PaperValue(138.7, None, "mm", "§II-B.1"),
    "model.cutout_diameter_mm": PaperValue(64.0, None, "mm", "§II-B.1"),
    "model.aperture_mm": PaperValue("≈ 240 x 170 mm", None, "", "§II-D"),
    "model.spacing_pose_mm": PaperValue(0.47, None, "mm", "§II-B.1"),
    "model.spacing_render_mm": PaperValue(0.125, None, "mm", "§II-B.1"),
    "model.n_feature_classes": PaperValue(5, None, "", "§II-B.1"),
    "render.n_splats": PaperValue(16, None, "", "§II-B.2"),
    "render.splat_sigma_mm": PaperValue(0.5, None, "mm", "§II-B.2"),
    "carm.gantry_angles_deg": PaperValue("−45° and +45° around PA", None, "", "§II-D"),
    "carm.network_input_px": PaperValue("310 x 240", None, "px", "§II-B.4"),
    "transducer.focal_length_mm": PaperValue(140.0, None, "mm", "§II-D"),
    "transducer.f_number": PaperValue(0.7, None, "", "§II-D"),
    # §III segmentation (Table I and text).
    **_table1(),
    "seg.global_accuracy": PaperValue(93.6, 1.9, "%", "§III"),
    "seg.weighted_iou": PaperValue(89.0, 3.21, "%", "§III"),
    "seg.mean_precision": PaperValue(95.6, 2.2, "%", "§III"),
    "seg.mean_recall": PaperValue(84.3, 3.3, "%", "§III"),
    "seg.anova_F": PaperValue(85.6, None, "", "§III, F(5, 1262)"),
    "seg.anova_df_between": PaperValue(5, None, "", "§III"),
    "seg.anova_df_within": PaperValue(1262, None, "", "§III"),
    "seg.anova_p": PaperValue("< 1e-5", None, "", "§III"),
    "seg.tukey_screws_vs_background_ci": PaperValue("[7.7, 10.1]", None, "%", "§III"),
    "seg.n_images": PaperValue(310, None, "", "§II-E.1"),
    # §III orientation regression.
    "angles.azimuth.pearson": PaperValue(99.1, None, "%", "§III"),
    "angles.elevation.pearson": PaperValue(99.9, None, "%", "§III"),
    "angles.azimuth.slope": PaperValue(1.078, None, "", "§III"),
    "angles.elevation.slope": PaperValue(1.048, None, "", "§III"),
    "angles.azimuth.intercept": PaperValue(-0.136, None, "deg", "§III"),
    "angles.elevation.intercept": PaperValue(-0.101, None, "deg", "§III"),
    "angles.azimuth.r2": PaperValue(0.983, None, "", "§III"),
    "angles.elevation.r2": PaperValue(0.999, None, "", "§III"),
    "angles.azimuth.mae": PaperValue(1.06, 0.71, "deg", "§III"),
    "angles.elevation.mae": PaperValue(2.34, 2.20, "deg", "§III"),
    # §III pose estimation (text and Table II).
    **_table2(),
    "pose.center_euclidean": PaperValue(1.38, 0.54, "mm", "§III"),
    "pose.center_mae.depth": PaperValue(0.69, 0.58, "mm", "§III"),
    "pose.center_mae.tb": PaperValue(0.52, 0.40, "mm", "§III"),
    "pose.center_mae.lr": PaperValue(0.81, 0.56, "mm", "§III"),
    "pose.center_bias.depth": PaperValue(0.01, None, "mm", "§III"),
    "pose.center_bias.tb": PaperValue(0.30, None, "mm", "§III"),
    "pose.center_bias.lr": PaperValue(-0.77, None, "mm", "§III"),
    "pose.margin_distance": PaperValue(1.04, 0.22, "mm", "§III"),
    "pose.radius_mae": PaperValue(0.51, 0.24, "mm", "§III"),
    "pose.n_studies": PaperValue(10, None, "", "§III"),
    # §III automated targeting.
    "targeting.euclidean": PaperValue(1.64, 0.34, "mm", "§III, abstract 1.4 ± 0.5"),
    "targeting.mae.depth": PaperValue(0.83, 0.65, "mm", "§III"),
    "targeting.mae.tb": PaperValue(0.46, 0.29, "mm", "§III"),
    "targeting.mae.lr": PaperValue(1.05, 0.58, "mm", "§III"),
    "targeting.bias.depth": PaperValue(-0.31, None, "mm", "§III"),
    "targeting.bias.tb": PaperValue(0.11, None, "mm", "§III"),
    "targeting.bias.lr": PaperValue(-1.01, None, "mm", "§III"),
    "targeting.radius_mae": PaperValue(0.5, 0.5, "mm", "abstract"),
    "targeting.n_studies": PaperValue(6, None, "", "§III"),
    "robot.repeatability_mm": PaperValue(0.03, None, "mm", "§II-C"),
}


def paper_value(key: str) -> PaperValue:
    """The paper's value for ``key``; a KeyError lists near keys when it is unknown."""
    try:
        return PAPER[key]
    except KeyError:
        prefix = key.split(".")[0]
        near = sorted(k for k in PAPER if k.startswith(prefix))[:12]
        raise KeyError(f"no paper value {key!r}; known keys with prefix {prefix!r}: {near}") from None
