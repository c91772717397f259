"""What the treatment tests share: a transducer orientation, a robot with a calibration that puts a
zone at its home pose, and samples of a ball."""

import numpy as np

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.robot import SimulatedUR5e
from histostudy.treatment import TreatmentZone

R_CT = rotation_about_axis([1.0, 0.3, 0.0], 2.6)  # a transducer orientation in the C-arm frame


def sphere_samples(centre, radius, step=0.5):
    g = np.arange(-radius, radius + step / 2, step)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    p = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return centre + p[np.linalg.norm(p, axis=1) <= radius]


def robot_zone_and_calibration(seed=1):
    """A robot, a zone, and a calibration that puts the zone centre at the robot's home TCP position;
    returns ``(robot, zone, T_base_carm, R_base_tcp)``."""
    robot = SimulatedUR5e(seed)
    T_home = robot.tcp_pose()
    zone = TreatmentZone([1.0, -2.0, 0.5], 20.0)
    R_base_carm = T_home[:3, :3] @ R_CT.T  # the transducer's home orientation is R_CT in the C-arm
    T_base_carm = make_transform(R_base_carm, T_home[:3, 3] - R_base_carm @ zone.centre_mm)
    return robot, zone, T_base_carm, T_home[:3, :3]
