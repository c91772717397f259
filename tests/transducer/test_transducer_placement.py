"""Tests of histostudy.transducer.placement: the paper's set-up pose."""

import numpy as np
import pytest

from histostudy.geometry import check_rigid
from histostudy.imaging import default_biplane
from histostudy.transducer import pose_facing

R = 138.7


def test_pose_facing_puts_the_transducer_above_the_patient():
    T = check_rigid(pose_facing())
    centre = T[:3, :3] @ [0, 0, R] + T[:3, 3]
    np.testing.assert_allclose(centre, [0, -R, 0], atol=1e-9)
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=1e-12)  # LR along patient left
    T2 = pose_facing((0, 1, 0), focal_point_mm=(5, 6, 7), axial_rotation_rad=np.pi / 2)
    np.testing.assert_allclose(T2[:3, 3], [5, 6, 7])
    np.testing.assert_allclose(T2[:3, 2], [0, -1, 0], atol=1e-12)
    view_a, _ = default_biplane()
    Tv = pose_facing(view_a)
    np.testing.assert_allclose(Tv[:3, 2], -view_a.principal_direction, atol=1e-12)
    with pytest.raises(ValueError, match="direction"):
        pose_facing((0, 0, 0))
