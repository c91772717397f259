"""Hand-made report folders: sections written by the real SectionWriter, and run records as the
pipeline writes them, so the report's tests run in milliseconds without a notebook."""

import numpy as np
import pandas as pd
import pytest

from histostudy.reporting import PAPER, SectionWriter


class ReportFolder:
    """A report output folder under construction: ``section(...)`` writes one section's results,
    ``run(...)`` the run record naming them in order."""

    def __init__(self, root):
        self.root = root
        self.names = []

    def section(self, name, *, title=None, compare=(), stand_ins=(), tables=(), image=False, text=()):
        """Write section ``name``: ``compare`` holds SectionWriter.compare keyword arguments,
        ``tables`` (name, DataFrame, caption) triples; ``image`` adds a 12x16 PNG figure."""
        w = SectionWriter(self.root / name, name, title or f"{name[:2]} · {name[3:]}", profile="smoke", seed=1)
        for kwargs in compare:
            w.compare(**kwargs)
        for lab, synthetic in stand_ins:
            w.stand_in(lab, synthetic)
        for table_name, df, caption in tables:
            w.table(table_name, df, caption)
        if image:
            rgb = np.zeros((12, 16, 3), np.uint8)
            rgb[..., 0] = 200
            w.image("shot", rgb, "A red figure")
        for para in text:
            w.text(para)
        w.save()
        self.names.append(name)
        return w

    def run(self, profile="smoke", *, statuses=None, parameters=None, failure=None, extra=()):
        """The run record: every written section (status "ok" unless ``statuses`` says otherwise)
        plus ``extra`` notebook names that have no results."""
        statuses = statuses or {}
        parameters = parameters or {}
        notebooks = [{"name": n, "status": statuses.get(n, "ok"), "seconds": 1.0,
                      "output_dir": str(self.root / n), "parameters": parameters.get(n, {})}
                     for n in [*self.names, *extra]]
        return {"profile": profile, "seed": 1, "provenance": {"git_commit": "abc", "versions": {"numpy": "2"}},
                "notebooks": notebooks, "failure": failure}

    @staticmethod
    def paper_comparison(key, **extra):
        """SectionWriter.compare keyword arguments that reproduce the paper's value of ``key`` exactly."""
        value = PAPER[key]
        ours = value.mean if value.sd is None else (value.mean, value.sd)
        return dict(key=key, label=value.label or key, ours=ours, unit=value.unit, **extra)

    @staticmethod
    def wide_table():
        """A table whose column names hold '|' (as notebook 04's variants table), text with '<' and
        '&', a missing value and enough columns to be wider than a phone."""
        return pd.DataFrame({"mode": ["paper", "fast"], "centre |depth|": [0.51, 1.2], "centre |tb|": [0.2, np.nan],
                             "note": ["a < b & c", "x_y *z*"], **{f"extra column {i}": [i, i + 1] for i in range(8)}})


@pytest.fixture
def folder(tmp_path):
    return ReportFolder(tmp_path)


