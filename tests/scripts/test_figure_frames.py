"""scripts/figure_frames.py on a small hand-made dataset: the chain it draws is the dataset's
(T_carm_transducer = T_carm_base @ T_base_flange @ T_flange_transducer, the sources of its views,
the box of its CBCT), and the figure the docs embed is there and small."""

import json
from pathlib import Path

import numpy as np
import pytest

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.imaging import Volume, default_biplane, save_views, save_volume_nifti

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def figure_frames(load_script):
    return load_script("figure_frames")


@pytest.fixture
def dataset(tmp_path):
    T_carm_base = make_transform(matrix_from_rotvec([0.1, -0.2, 0.3]), [-400.0, 200.0, -250.0])
    T_flange_transducer = make_transform(matrix_from_rotvec([np.pi, 0, 0]), [0.5, -1.0, 205.0])
    flanges = [make_transform(matrix_from_rotvec([0.2 * k, 0.1, -0.3]), [-450.0 + 10 * k, -200.0, 400.0])
               for k in range(2)]
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "flange_poses.json").write_text(json.dumps(
        {"T_base_flange": [F.tolist() for F in flanges]}))
    (tmp_path / "truth.json").write_text(json.dumps({"T_carm_base": T_carm_base.tolist(),
                                                     "T_flange_transducer": T_flange_transducer.tolist()}))
    save_views(tmp_path / "views.json", default_biplane())
    save_volume_nifti(Volume(np.zeros((5, 6, 7)), 2.0, (-6.0, -5.0, -4.0)), tmp_path / "cbct.nii.gz")
    return tmp_path, T_carm_base @ flanges[1] @ T_flange_transducer


def test_the_chain_drawn_is_the_datasets(figure_frames, dataset, tmp_path):
    folder, T_carm_transducer = dataset
    chain = figure_frames.load_chain(folder, 1)
    np.testing.assert_allclose(chain["T_carm_transducer"], T_carm_transducer, atol=1e-9)
    np.testing.assert_allclose(sorted(s[0] for s in chain["sources"].values()),
                               sorted(v.source_mm[0] for v in default_biplane()))
    np.testing.assert_allclose(chain["box"][0], [-6.0, -5.0, -4.0])
    np.testing.assert_allclose(chain["box"][1], [-6.0 + 12, -5.0 + 10, -4.0 + 8])
    out = tmp_path / "frames.png"
    assert figure_frames.main([str(folder), "--station", "1", "--output", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size < 300_000
    with pytest.raises(SystemExit, match="--station 5"):
        figure_frames.main([str(folder), "--station", "5", "--output", str(out)])
    with pytest.raises(SystemExit, match="no truth.json"):
        figure_frames.main([str(tmp_path / "elsewhere"), "--output", str(out)])


def test_the_docs_embed_the_figure_and_it_is_small():
    figure = REPO / "docs" / "img" / "frames.png"
    assert figure.is_file() and figure.stat().st_size <= 300 * 1024
    assert "](img/frames.png)" in (REPO / "docs" / "your-data.md").read_text()
