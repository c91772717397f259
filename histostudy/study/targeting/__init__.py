"""Notebook 05: the paper's automated targeting study (§II-C, §II-D, §II-E.4, §III) on synthetic data.

One experiment, as in the lab, in four stages:

1. **Ground truth set-up** (what the lab had but did not know): the robot base placed beside the
   table (``T_carm_base``, drawn), the transducer mounted below the flange (``T_flange_transducer``:
   focal point 200-300 mm along the tool axis plus a few mm / degrees of mounting error, drawn),
   the *physical* transducer (its acoustic focal point differs from the digital model's) and a
   bubble-cloud offset from it (configurable, default 0).
2. **Calibration** (§II-C): the robot moves the flange to ``n_calibration_poses`` preprogrammed
   poses about a start pose above the phantom (the transducer pointing down, tilted about
   different horizontal axes and turned about its own axis so that the motions determine
   AX = XB); at each the robot's measured ``T_base_flange`` is read and a biplane pair is rendered
   from the TRUE transducer pose (``T_carm_base_true @ T_base_flange_reached @
   T_flange_transducer_true``); the pose is estimated (fast mode; the stages given, in notebook 05
   the shipped U-Net and VGG19, otherwise the Table I-degraded oracle segmenter and the oracle
   orientation) and :func:`histostudy.calibration.calibrate` run on the pairs.
   Its residuals are checked against a stated bound (:meth:`HandEyeCalibration.check`): targeting
   refuses to run on a calibration that fails it.
3. **Pre-treatment CBCT** of the layered phantom; a target picked inside it with the whole zone
   (20 or 25 mm) and the segmentation window inside the phantom.
4. **Automatic positioning and treatment**: the TCP is set to the estimated focal point, the
   transducer pointed down (its propagation along the world's posterior +y, the axial rotation of
   the flange pointing straight down), the robot moved (it checks reach and workspace before it
   moves), the zone treated (:func:`histostudy.treatment.plan_treatment` /
   :func:`~histostudy.treatment.execute_treatment`, journal in a temporary folder), the bubble
   clouds placed at the TRUE focal points of the physical transducer for the reached robot
   poses (plus the offset), the layers mixed, a post-treatment CBCT simulated and the zone
   segmented (:func:`histostudy.treatment.zone.segment_treatment_zone`, the stand-in for the manual
   annotation).

Errors (§II-E.4): Euclidean distance between the intended target and the segmented zone's
centroid; its components along depth/TB/LR (the commanded transducer axes at the target); the
segmented sphere radius against the planned radius; and the calibration against the ground
truth (rotation and translation of ``T_flange_transducer`` and ``T_carm_base``, and the
calibration's error at the target: where the true chain puts the focal point for the commanded
flange pose).

**Bias correction** (§IV: "this could be further improved by including the pose estimation bias
during the calibration"). Fluoroscopy cannot see the bias: the calibration's own residuals are
zero-mean by construction (its translation is the least-squares fit to the estimated focal
points), and the offset between the digital model's focal point and the bubble cloud
(manufacturing, aberration) moves no transducer feature. So the bias is learnt as the
conventional workflow's test pulse does (§II-A step 3), with one **calibration treatment**: after
the hand-eye calibration, a test zone is treated in a separate calibration phantom, its
post-treatment CBCT segmented, and the offset of its centroid from the intended target expressed
in the transducer frame, ``b = R_des^T (centroid - target)``. The corrected TCP is the estimated
focal point moved by ``b`` (``T_flange_tcp = X_est @ Trans(b)``): aiming that TCP at a target puts
the bubble cloud where the test lesion says it lands. Each experiment treats its target twice
(two identical phantoms, the same pre-treatment CBCT and target): once as the paper did (no
correction) and once with the corrected TCP, so both are reported on the same target.

The robot is a :class:`~histostudy.robot.SimulatedUR5e` or an :class:`~histostudy.robot.RTDERobot`
driving the simulated UR controller through the real ``ur_rtde`` client (:func:`rtde_robot`); both
take the same integer seed for the repeatability noise (the controller's ``--seed``), so the same
study seed gives the same moves and the same numbers on either (up to the float round trip of the
metre/axis-angle boundary, far below 1e-6 mm).

Its modules, one job each: the configuration and the ground truth an experiment draws (``_setup``),
the simulated robots (``_robots``), hand-eye calibration (``_calibration``, §II-C), positioning the
TCP on a CBCT target (``_positioning``, §II-D), treating a zone (``_treatment``), one experiment and
the study of several (``_experiment``), §III's figures, tables and comparisons (``_summary``), Fig.
7's cuts and scene (``_figures``), the notebook's parameters (:class:`TargetingSectionConfig`), set-up
(:func:`prepare`) and parts recorded by :func:`record` (``_notebook``).
"""

from . import _calibration, _experiment, _figures, _notebook, _positioning, _robots, _setup, _summary, _treatment
from ._calibration import HALF_TURN, calibrate_robot, calibration_poses, config_focal_flange
from ._experiment import calibration_errors, run_targeting_experiment, run_targeting_study, zone_errors
from ._figures import SceneFigure, fig7_figures, plot_target_slices, scene_figure
from ._notebook import (
                        RECORDED_PARAMETERS,
                        ROBOTS,
                        SECTION_TITLE,
                        NotebookSeeds,
                        SectionPart,
                        SensitivitySection,
                        TargetingRun,
                        TargetingSectionConfig,
                        TargetingSetup,
                        calibration_part,
                        closing_part,
                        closing_text,
                        config_from_parameters,
                        experiments_section,
                        notebook_seeds,
                        prepare,
                        prepare_study,
                        record,
                        run_prepared_study,
                        sensitivity_section,
                        stand_ins,
                        targeting_part,
)
from ._positioning import DOWN, position_for_target, scene_at_target, target_orientation, tcp_for_target
from ._robots import InaccurateArm, KinematicError, reported_flange_pose, robot_seed, rtde_robot, sim_robot
from ._setup import GroundTruth, TargetingError, TargetingStudyConfig, draw_ground_truth, start_joints
from ._summary import (
                        CALIBRATION_TABLE_CAPTION,
                        ERROR_TABLE_CAPTION,
                        SUMMARY_TABLE_CAPTION,
                        calibration_sensitivity_table,
                        calibration_table,
                        error_table,
                        first_robot_rows,
                        robot_max_difference,
                        sensitivity_caption,
                        sensitivity_medians,
                        summary,
                        targeting_comparisons,
                        targeting_values,
)
from ._treatment import learn_bubble_bias, phantom_for, treat_zone

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_calibration.__all__, *_experiment.__all__, *_figures.__all__, *_notebook.__all__,
                              *_positioning.__all__, *_robots.__all__, *_setup.__all__, *_summary.__all__, *_treatment.__all__]))
