"""histostudy.transducer.symmetry: the half turn about the transducer axis that no image can see."""

import numpy as np
import pytest

from histostudy.transducer import HALF_TURN, Feature, TransducerModel, half_turn_symmetric


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


def test_the_papers_transducer_maps_onto_itself_under_a_half_turn(model):
    assert half_turn_symmetric(model)
    np.testing.assert_allclose(HALF_TURN @ HALF_TURN, np.eye(3))
    np.testing.assert_allclose(HALF_TURN @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0])  # the beam axis stays


def test_one_screw_moved_breaks_the_symmetry(model):
    screws = model.points[Feature.SCREWS].copy()
    # every screw point whose x > 0 moves 3 mm along y: the screw pattern is no longer its half turn
    screws[screws[:, 0] > 0, 1] += 3.0
    moved = TransducerModel(spec=model.spec, spacing_mm=model.spacing_mm,
                            points={**model.points, Feature.SCREWS: screws}, weights=model.weights,
                            grid_step_mm=model.grid_step_mm)
    assert not half_turn_symmetric(moved)
    assert half_turn_symmetric(moved, tolerance_mm=5.0)  # within a coarser tolerance it still is


def test_the_physical_transducers_deviation_is_seen_at_the_grid_spacing():
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(0))
    assert not half_turn_symmetric(physical)


@pytest.mark.parametrize("tolerance", [0, -1.0, np.nan, "1"])
def test_a_bad_tolerance_is_refused(model, tolerance):
    with pytest.raises(ValueError, match="tolerance_mm must be"):
        half_turn_symmetric(model, tolerance_mm=tolerance)


def test_only_a_model_is_accepted():
    with pytest.raises(TypeError, match="TransducerModel"):
        half_turn_symmetric(np.zeros((3, 3)))
