"""A campaign of bad inputs across the public entry points, as a new user would make them: each must
fail at the call with an error that names the argument (or file) it is about, before any work.

The journal's faults, the profiles, the volume files and the checkpoints have their own suites
(tests/treatment/test_treatment_journal.py, tests/reporting/test_profiles.py,
tests/imaging/test_*_io.py, tests/learning/test_checkpoints.py); this file covers the calls in
between, so that the campaign can be counted in one place."""

import numpy as np
import pytest

from histostudy.calibration import calibrate
from histostudy.calibration.axxb import solve_axxb
from histostudy.imaging import (
    Frame,
    FrameRenderConfig,
    View,
    Volume,
    default_biplane,
    load_volume,
    render_frame,
    simulate_cbct,
)
from histostudy.pose import PoseConfig, estimate_pose
from histostudy.robot import SimulatedUR5e
from histostudy.transducer import TransducerModel, check_label_image, pose_facing
from histostudy.treatment import TreatmentZone, execute_treatment, plan_treatment, segment_treatment_zone

NAN, INF = float("nan"), float("inf")


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.94)


@pytest.fixture(scope="module")
def view():
    return default_biplane()[0]


def _zone():
    return TreatmentZone([0.0, 0.0, 0.0], 20.0)


def _volume():
    return Volume(np.zeros((8, 8, 8)), 1.0)


# (case id, call taking (model, view, tmp_path), exception types, what the message must name)
CASES = [
    # views and frames
    ("view primary nan", lambda m, v, t: View.from_gantry(NAN), ValueError, "primary"),
    ("view pixel 0", lambda m, v, t: View.from_gantry(0.0, pixel_mm=0.0), ValueError, "pixel_mm"),
    ("view shape negative", lambda m, v, t: View.from_gantry(0.0, shape=(-4, 10)), ValueError, "shape"),
    ("frame image 3-D", lambda m, v, t: Frame(np.zeros((2,) + v.shape), v), ValueError, "image"),
    ("frame image nan", lambda m, v, t: Frame(np.full(v.shape, NAN), v), ValueError, "image"),
    ("frame labels 300", lambda m, v, t: Frame(np.zeros(v.shape), v, labels=np.full(v.shape, 300)), ValueError,
     "labels"),
    ("frame labels -1", lambda m, v, t: Frame(np.zeros(v.shape), v, labels=np.full(v.shape, -1)), ValueError,
     "labels"),
    ("frame labels 2.7", lambda m, v, t: Frame(np.zeros(v.shape), v, labels=np.full(v.shape, 2.7)), ValueError,
     "labels"),
    ("frame pose not rigid", lambda m, v, t: Frame(np.zeros(v.shape), v, T_carm_transducer=2 * np.eye(4)),
     ValueError, "T_carm_transducer"),
    ("label image string", lambda m, v, t: check_label_image(np.array([["a"]])), ValueError, "labels"),
    # rendering
    ("render photons 0", lambda m, v, t: render_frame(m, pose_facing(), v, rng=np.random.default_rng(0),
                                                      photons_per_pixel=0.0), ValueError, "photons_per_pixel"),
    ("render splats 0", lambda m, v, t: render_frame(m, pose_facing(), v, rng=np.random.default_rng(0),
                                                     n_splats=0), ValueError, "n_splats"),
    ("render sigma nan", lambda m, v, t: render_frame(m, pose_facing(), v, rng=np.random.default_rng(0),
                                                      splat_sigma_mm=NAN), ValueError, "splat_sigma_mm"),
    ("render pose nan", lambda m, v, t: render_frame(m, np.full((4, 4), NAN), v, rng=np.random.default_rng(0)),
     ValueError, "T_carm_transducer"),
    ("render rng int", lambda m, v, t: render_frame(m, pose_facing(), v, rng=3), (TypeError, ValueError), "rng"),
    ("render labels_from", lambda m, v, t: render_frame(m, pose_facing(), v, rng=np.random.default_rng(0),
                                                        labels_from="both"), ValueError, "labels_from"),
    ("settings background", lambda m, v, t: FrameRenderConfig(background="water"), ValueError, "background"),
    ("settings photons bool", lambda m, v, t: FrameRenderConfig(photons_per_pixel=True), ValueError,
     "photons_per_pixel"),
    ("model spacing 0", lambda m, v, t: TransducerModel.build(spacing_mm=0.0), ValueError, "spacing_mm"),
    ("model spacing nan", lambda m, v, t: TransducerModel.build(spacing_mm=NAN), ValueError, "spacing_mm"),
    # pose estimation: checked at the call, nothing computed first
    ("pose max_rms nan", lambda m, v, t: PoseConfig(max_rms_px=NAN), ValueError, "max_rms_px"),
    ("pose search centre 2-D", lambda m, v, t: PoseConfig(search_centre_mm=(0, 0)), ValueError,
     "search_centre_mm"),
    ("pose mode", lambda m, v, t: PoseConfig(mode="quick"), ValueError, "mode"),
    ("pose maps", lambda m, v, t: PoseConfig(distance_maps="chamfer"), ValueError, "distance_maps"),
    ("pose unknown keyword", lambda m, v, t: estimate_pose([Frame(np.zeros(v.shape), v)], m, max_rms=3), TypeError,
     "max_rms"),
    ("pose no frames", lambda m, v, t: estimate_pose([], m), ValueError, "frames"),
    ("pose bad threshold before work", lambda m, v, t: estimate_pose([Frame(np.zeros(v.shape), v)], m,
                                                                     max_view_disagreement_mm=-1.0),
     ValueError, "max_view_disagreement_mm"),
    # calibration
    ("axxb one motion", lambda m, v, t: solve_axxb([np.eye(4)], [np.eye(4)]), ValueError, "A_list"),
    ("axxb not rigid", lambda m, v, t: solve_axxb([np.eye(4), 2 * np.eye(4)], [np.eye(4)] * 2), ValueError,
     "A_list"),
    ("calibrate lengths", lambda m, v, t: calibrate([np.eye(4)] * 4, [np.eye(4)] * 3), ValueError, "pair up"),
    ("calibrate pairs", lambda m, v, t: calibrate([np.eye(4)] * 4, [np.eye(4)] * 4, pairs="some"), ValueError,
     "pairs"),
    # robot
    ("robot pose nan", lambda m, v, t: SimulatedUR5e(0).move_linear(np.full((4, 4), NAN)), ValueError, "T_base_tcp"),
    ("robot speed 0", lambda m, v, t: SimulatedUR5e(0).move_linear(SimulatedUR5e(0).tcp_pose(), 0.0), ValueError,
     "speed_mm_s"),
    ("robot speed inf", lambda m, v, t: SimulatedUR5e(0).move_linear(SimulatedUR5e(0).tcp_pose(), INF), ValueError,
     "speed_mm_s"),
    ("robot seed float", lambda m, v, t: SimulatedUR5e(1.7), (TypeError, ValueError), "rng|seed"),
    # volumes and the treatment
    ("volume spacing 0", lambda m, v, t: Volume(np.zeros((2, 2, 2)), 0.0), ValueError, "spacing_mm"),
    ("volume 2-D", lambda m, v, t: Volume(np.zeros((2, 2)), 1.0), ValueError, "data"),
    ("cbct noise negative", lambda m, v, t: simulate_cbct(_volume(), 0, noise_sd_hu=-1.0), ValueError,
     "noise_sd_hu"),
    ("cbct truth not a volume", lambda m, v, t: simulate_cbct(np.zeros((4, 4, 4)), 0), TypeError, "truth"),
    ("load volume missing", lambda m, v, t: load_volume(t / "none.nii"), (FileNotFoundError, ValueError), "none.nii"),
    ("load volume unknown type", lambda m, v, t: load_volume((t / "v.xyz").write_text("x") and t / "v.xyz"),
     ValueError, "v.xyz"),
    ("zone diameter 0", lambda m, v, t: TreatmentZone([0, 0, 0], 0.0), ValueError, "diameter"),
    ("zone centre 2-D", lambda m, v, t: TreatmentZone([0, 0], 20.0), ValueError, "centre_mm"),
    ("plan spacing nan", lambda m, v, t: plan_treatment(_zone(), NAN), ValueError, "spacing_mm"),
    ("plan pulses 0", lambda m, v, t: plan_treatment(_zone(), 5.0, pulses_per_point=0), ValueError,
     "pulses_per_point"),
    ("plan axes not a rotation", lambda m, v, t: plan_treatment(_zone(), 5.0, axes=2 * np.eye(3)), ValueError,
     "axes"),
    ("treat plan type", lambda m, v, t: execute_treatment(SimulatedUR5e(0), "plan", np.eye(4), np.eye(3),
                                                          t / "j.sqlite"), TypeError, "plan"),
    ("treat calibration", lambda m, v, t: execute_treatment(SimulatedUR5e(0), plan_treatment(_zone(), 5.0),
                                                            np.eye(3), np.eye(3), t / "j.sqlite"), ValueError,
     "T_base_carm"),
    ("treat policy", lambda m, v, t: execute_treatment(SimulatedUR5e(0), plan_treatment(_zone(), 5.0), np.eye(4),
                                                       np.eye(3), t / "j.sqlite", on_uncertain="ask"), ValueError,
     "on_uncertain"),
    ("treat deliver", lambda m, v, t: execute_treatment(SimulatedUR5e(0), plan_treatment(_zone(), 5.0), np.eye(4),
                                                        np.eye(3), t / "j.sqlite", deliver=5), TypeError, "deliver"),
    ("zone roi shape", lambda m, v, t: segment_treatment_zone(_volume(), np.ones((2, 2, 2), bool)), ValueError,
     "roi_mask"),
    ("zone window 0", lambda m, v, t: segment_treatment_zone(_volume(), np.ones((8, 8, 8), bool), window_mm=0.0),
     ValueError, "window_mm"),
]


@pytest.mark.parametrize("name, call, errors, names", CASES, ids=[c[0] for c in CASES])
def test_a_bad_input_fails_at_the_call_naming_what_is_wrong(name, call, errors, names, model, view, tmp_path):
    with pytest.raises(errors, match=names):
        call(model, view, tmp_path)
    assert not (tmp_path / "j.sqlite").exists()  # a refused treatment wrote no journal


def test_the_campaign_is_as_broad_as_it_says():
    assert len(CASES) >= 50 and len({c[0] for c in CASES}) == len(CASES)
