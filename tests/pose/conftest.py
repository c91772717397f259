"""Fixtures the tracking tests share (tests/pose/tracking/). Loading this file puts tests/pose on
sys.path (pytest's default "prepend" import mode), so the tests of the sub-folders import
pose_frames.py too."""

import pytest

from histostudy.imaging import default_biplane
from histostudy.transducer import TransducerModel


@pytest.fixture(scope="module")
def models():
    """The pose model (0.47 mm) and the finer model the frames are rendered from (0.25 mm)."""
    return TransducerModel.build(spacing_mm=0.47), TransducerModel.build(spacing_mm=0.25)


@pytest.fixture(scope="module")
def views():
    """The paper's biplane at half resolution: fast to render and segment."""
    return [v.scaled(0.5) for v in default_biplane()]
