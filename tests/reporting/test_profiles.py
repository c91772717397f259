"""Profiles: built-ins load, parameters merge with the right precedence, bad names fail clearly, and a
profile is checked against the notebooks' parameters cells (misspelt keys and tables, bad seeds)."""

import nbformat
import pytest

from histostudy.reporting import PROFILE_NAMES, Profile, load_profile
from histostudy.reporting.pipeline import discover_notebooks
from histostudy.reporting.profiles import notebook_parameters, validate_profile


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


# --- validation against the notebooks' parameters cells ---------------------------------------


def _notebook(path, parameters):
    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell(parameters)
    cell.metadata["tags"] = ["parameters"]
    nb.cells = [nbformat.v4.new_markdown_cell("# toy"), cell, nbformat.v4.new_code_cell("print(seed)")]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.write(nb, path)
    return path


@pytest.fixture
def toy_notebooks(tmp_path):
    folder = tmp_path / "notebooks"
    folder.mkdir()
    _notebook(folder / "01_render.ipynb", 'profile = "smoke"\nseed = 0\noutput_dir = "."\n'
                                          'photons_per_pixel = 5e4  # dose\nrender_spacing_mm = 0.125\n')
    _notebook(folder / "02_segmentation.ipynb", 'profile = "smoke"\nseed = 0\noutput_dir = "."\n'
                                                'photons_per_pixel = 5e4\nn_eval_images: int = 4\n'
                                                'modes = [\n    "paper",\n    "fast",\n]\na, b = 1, 2\n')
    return sorted(folder.glob("*.ipynb"))


def _profile(tmp_path, text, name="mine.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_profile(path)


def test_notebook_parameters_reads_the_tagged_cell(toy_notebooks, tmp_path):
    assert notebook_parameters(toy_notebooks[1]) == ("profile", "seed", "output_dir", "photons_per_pixel",
                                                     "n_eval_images", "modes", "a", "b")
    untagged = nbformat.v4.new_notebook()
    untagged.cells = [nbformat.v4.new_code_cell("x = 1")]
    nbformat.write(untagged, tmp_path / "03_untagged.ipynb")
    assert notebook_parameters(tmp_path / "03_untagged.ipynb") == ()


def test_notebook_parameters_match_papermill_on_the_study_notebooks():
    import papermill

    for nb in discover_notebooks():
        assert notebook_parameters(nb) == tuple(papermill.inspect_notebook(str(nb))), nb.stem


@pytest.mark.parametrize("name", PROFILE_NAMES)
def test_shipped_profiles_fit_the_study_notebooks(name):
    validate_profile(load_profile(name), discover_notebooks())


def test_valid_toy_profile_passes(toy_notebooks, tmp_path):
    p = _profile(tmp_path, 'seed = 1\n[common]\nphotons_per_pixel = 1e3\n'
                           '[notebooks.02_segmentation]\nn_eval_images = 2\nmodes = ["fast"]\n')
    validate_profile(p, toy_notebooks)


def test_misspelt_notebook_key_names_key_table_file_and_suggestion(toy_notebooks, tmp_path):
    p = _profile(tmp_path, 'seed = 1\n[notebooks.02_segmentation]\nn_eval_image = 2\n')
    with pytest.raises(ValueError) as err:
        validate_profile(p, toy_notebooks)
    msg = str(err.value)
    assert str(tmp_path / "mine.toml") in msg
    assert "'n_eval_image' in [notebooks.02_segmentation]" in msg and "did you mean 'n_eval_images'?" in msg


def test_key_of_another_notebook_is_refused_in_a_notebook_table(toy_notebooks, tmp_path):
    p = _profile(tmp_path, 'seed = 1\n[notebooks.01_render]\nn_eval_images = 2\n')
    with pytest.raises(ValueError, match=r"'n_eval_images' in \[notebooks.01_render\] is not a parameter"):
        validate_profile(p, toy_notebooks)


def test_misspelt_notebook_table_gets_the_nearest_stem(toy_notebooks, tmp_path):
    p = _profile(tmp_path, 'seed = 1\n[notebooks.02_segmentaton]\nn_eval_images = 2\n')
    with pytest.raises(ValueError, match=r"\[notebooks.02_segmentaton\] names no notebook; "
                                         r"did you mean \[notebooks.02_segmentation\]\?"):
        validate_profile(p, toy_notebooks)


def test_common_key_must_be_a_parameter_of_some_notebook(toy_notebooks, tmp_path):
    # a parameter of one notebook only is fine in [common] (the shipped profiles' rule)
    validate_profile(_profile(tmp_path, 'seed = 1\n[common]\nrender_spacing_mm = 0.25\n'), toy_notebooks)
    p = _profile(tmp_path, 'seed = 1\n[common]\nphotons_per_pixl = 1e3\n')
    with pytest.raises(ValueError, match=r"'photons_per_pixl' in \[common\].*did you mean 'photons_per_pixel'\?"):
        validate_profile(p, toy_notebooks)


@pytest.mark.parametrize("table", ["[common]", "[notebooks.01_render]"])
@pytest.mark.parametrize("key", ["seed", "profile", "output_dir"])
def test_tables_may_not_set_what_the_run_sets(toy_notebooks, tmp_path, table, key):
    p = _profile(tmp_path, f'seed = 1\n{table}\n{key} = 3\n')
    with pytest.raises(ValueError, match=rf"'{key}' in \[.*is set by the run itself"):
        validate_profile(p, toy_notebooks)


def test_all_problems_are_reported_together(toy_notebooks, tmp_path):
    p = _profile(tmp_path, 'seed = 1\n[common]\nfoo = 1\n[notebooks.01_rendr]\nx = 1\n')
    with pytest.raises(ValueError, match=r"has 2 problems:\n  - key 'foo'.*\n  - table \[notebooks.01_rendr\]"):
        validate_profile(p, toy_notebooks)


@pytest.mark.parametrize("value, shown", [("1.7", "1.7 (float)"), ("true", "True (bool)"), ('"7"', "'7' (str)"),
                                          ("2.0", "2.0 (float)"), ("-1", "-1")])
def test_seed_that_is_not_a_non_negative_integer_is_refused(tmp_path, value, shown):
    path = tmp_path / "bad.toml"
    path.write_text(f"seed = {value}\n")
    with pytest.raises(ValueError) as err:
        load_profile(path)
    msg = str(err.value)
    assert str(path) in msg and "'seed' must be a non-negative integer" in msg and f"got {shown}" in msg


def test_seed_checked_on_a_profile_built_in_code(toy_notebooks):
    with pytest.raises(ValueError, match=r"profile 'hand': 'seed' must be a non-negative integer, got 1.7"):
        validate_profile(Profile(name="hand", seed=1.7), toy_notebooks)


def test_unknown_top_level_key_and_table_get_suggestions(tmp_path):
    path = tmp_path / "top.toml"
    path.write_text('seed = 1\ndescriptoin = "x"\n[comon]\nn_splats = 4\n')
    with pytest.raises(ValueError) as err:
        load_profile(path)
    msg = str(err.value)
    assert str(path) in msg
    assert "'descriptoin'; did you mean 'description'?" in msg and "'comon'; did you mean 'common'?" in msg


def test_bad_top_level_types_and_toml_are_refused(tmp_path):
    path = tmp_path / "types.toml"
    path.write_text('seed = 1\nname = 5\ncommon = 3\nnotebooks = { 01_a = 2 }\n')
    with pytest.raises(ValueError, match=r"(?s)3 problems.*'name' must be a string.*'common' must be a table"
                                         r".*\[notebooks.<stem>\] entries must be tables"):
        load_profile(path)
    path.write_text("seed = \n")
    with pytest.raises(ValueError, match=r"types.toml is not valid TOML"):
        load_profile(path)
