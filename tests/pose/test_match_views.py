"""histostudy.pose.match_views: the view of each frame file, by order or by the file's stem, as
``histostudy pose`` and ``frames_from_files`` both read a views file."""

import pytest

from histostudy.imaging import default_biplane, save_views
from histostudy.pose import frames_from_files, match_views


def test_views_are_matched_by_order_then_by_stem_and_a_missing_one_is_named(tmp_path):
    a, b = default_biplane(shape=(16, 20), pixel_mm=18.0)
    assert match_views([a, b], ["x.dcm", "y.dcm"]) == [a, b]  # as many: by order, names aside
    assert match_views([a, b], ["B.npy"]) == [b]              # fewer files: by the stem
    with pytest.raises(ValueError, match=r"holds 2 views for 1 frame files and none named as the stem of \['C.npy'\]"):
        match_views([a, b], ["C.npy"])
    save_views(tmp_path / "views.json", [a, b])
    with pytest.raises(ValueError, match=r"^views file '.*views.json' holds 2 views for 1 frame files"):
        frames_from_files([tmp_path / "C.npy"], tmp_path / "views.json")
