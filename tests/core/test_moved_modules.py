"""histostudy.core.moved_modules: renamed classes keep their 0.1.0 names for a version, with a warning.
(The moved module paths are checked in tests/test_layers.py.)"""

import importlib
import warnings

import pytest

from histostudy.core import MOVED_MODULES_REMOVED_IN, renamed_attributes

#: (module, old name, new name) of every class renamed by the configuration naming rule
#: (docs/architecture.md, "Configuration classes").
RENAMED = [
    ("histostudy.imaging", "RenderSettings", "FrameRenderConfig"),
    ("histostudy.imaging.render", "RenderSettings", "FrameRenderConfig"),
    ("histostudy.imaging.render_settings", "RenderSettings", "FrameRenderConfig"),
    ("histostudy.imaging", "AbdomenParams", "AbdomenSpec"),
    ("histostudy.imaging", "PhantomParams", "PhantomSceneSpec"),
    ("histostudy.imaging.anatomy", "PhantomParams", "PhantomSceneSpec"),
    ("histostudy.imaging.anatomy_params", "AbdomenParams", "AbdomenSpec"),
    ("histostudy.study.pose", "PoseSectionParameters", "PoseSectionConfig"),
    ("histostudy.study.pose_config", "PoseSectionParameters", "PoseSectionConfig"),
    ("histostudy.robot.kinematics", "DHParameters", "DHSpec"),
    ("histostudy.pose", "PoseOptions", "PoseConfig"),
    ("histostudy.pose.options", "PoseOptions", "PoseConfig"),
    ("histostudy.pose", "TrackingOptions", "TrackingConfig"),
    ("histostudy.pose.tracking", "TrackingOptions", "TrackingConfig"),
    ("histostudy.pose.tracking_options", "TrackingOptions", "TrackingConfig"),
]


@pytest.mark.parametrize("module, old, new", RENAMED)
def test_an_old_class_name_gives_the_new_class_with_a_warning(module, old, new):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the module path may be an old one too
        mod = importlib.import_module(module)
    with pytest.warns(DeprecationWarning, match=rf"[.]{old} is deprecated and goes in histostudy "
                                                 rf"{MOVED_MODULES_REMOVED_IN.replace('.', '[.]')}: use {new} instead"):
        cls = getattr(mod, old)
    assert cls is getattr(mod, new)


def test_other_missing_names_still_raise_attribute_error():
    namespace = {"__name__": "somewhere", "New": object}
    getter = renamed_attributes(namespace, {"Old": "New"})
    with pytest.warns(DeprecationWarning):
        assert getter("Old") is namespace["New"]
    with pytest.raises(AttributeError, match="module 'somewhere' has no attribute 'Missing'"):
        getter("Missing")
