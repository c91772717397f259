"""Profiles: built-ins load, parameters merge with the right precedence, bad names fail clearly."""

import pytest

from histostudy.reporting import PROFILE_NAMES, load_profile


@pytest.mark.parametrize("name", PROFILE_NAMES)
def test_builtin_profiles_load_and_name_themselves(name):
    p = load_profile(name)
    assert p.name == name and isinstance(p.seed, int) and p.description
    params = p.parameters_for("01_transducer_and_projections")
    assert params["profile"] == name and params["seed"] == p.seed
    assert params["render_spacing_mm"] == 0.125  # the paper's rendering model


def test_notebook_table_overrides_common(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text('seed = 5\n[common]\nx = 1\ny = 2\n[notebooks.02_a]\ny = 3\n')
    p = load_profile(path)
    assert p.name == "mine"
    assert p.parameters_for("02_a") == {"profile": "mine", "seed": 5, "x": 1, "y": 3}
    assert p.parameters_for("03_b") == {"profile": "mine", "seed": 5, "x": 1, "y": 2}


def test_unknown_profile_names_the_value_and_the_choices():
    with pytest.raises(ValueError, match=r"'fast'.*smoke, standard, paper"):
        load_profile("fast")


def test_profile_without_seed_is_rejected(tmp_path):
    path = tmp_path / "noseed.toml"
    path.write_text('name = "x"\n')
    with pytest.raises(ValueError, match="seed"):
        load_profile(path)
