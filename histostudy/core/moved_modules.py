"""Old module paths that still import, with a DeprecationWarning, after a family of modules became a
sub-package (docs/architecture.md, "Where modules moved"; CHANGELOG.md names the version they go).

Renamed classes go the same way: :func:`renamed_attributes` gives a module the ``__getattr__`` that
returns the new class for its old name, with the same warning.

One table, :data:`MOVED_MODULES` (old dotted path -> new dotted path), and one import hook that
:func:`install` puts on ``sys.meta_path`` when ``histostudy`` is imported: ``import
histostudy.study.targeting_setup`` returns the very module object of
``histostudy.study.targeting._setup``, so a user's script and a pickle made before the move both
keep working, and ``isinstance`` checks see one class.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

__all__ = ["MOVED_MODULES", "MOVED_MODULES_REMOVED_IN", "install", "renamed_attributes"]

#: The version whose release removes the old paths of :data:`MOVED_MODULES`.
MOVED_MODULES_REMOVED_IN = "0.3.0"

#: Old dotted module path -> the module it now is.
MOVED_MODULES: dict[str, str] = {
    "histostudy.study.pose_estimation": "histostudy.study.pose",
    "histostudy.study.pose_config": "histostudy.study.pose._config",
    "histostudy.study.pose_experiments": "histostudy.study.pose._experiments",
    "histostudy.study.pose_geometry": "histostudy.study.pose._geometry",
    "histostudy.study.pose_metrics": "histostudy.study.pose._metrics",
    "histostudy.study.pose_reference": "histostudy.study.pose._reference",
    "histostudy.study.pose_report_tables": "histostudy.study.pose._report_tables",
    "histostudy.study.pose_robustness": "histostudy.study.pose._robustness",
    "histostudy.study.pose_section": "histostudy.study.pose._section",
    "histostudy.study.pose_sweeps": "histostudy.study.pose._sweeps",
    "histostudy.study.projector_comparison": "histostudy.study.pose._projectors",
    "histostudy.study.targeting_calibration": "histostudy.study.targeting._calibration",
    "histostudy.study.targeting_experiment": "histostudy.study.targeting._experiment",
    "histostudy.study.targeting_figures": "histostudy.study.targeting._figures",
    "histostudy.study.targeting_notebook": "histostudy.study.targeting._notebook",
    "histostudy.study.targeting_positioning": "histostudy.study.targeting._positioning",
    "histostudy.study.targeting_robots": "histostudy.study.targeting._robots",
    "histostudy.study.targeting_setup": "histostudy.study.targeting._setup",
    "histostudy.study.targeting_summary": "histostudy.study.targeting._summary",
    "histostudy.study.targeting_treatment": "histostudy.study.targeting._treatment",
    "histostudy.study.your_data_live": "histostudy.study.your_data._live",
    "histostudy.study.error_budget": "histostudy.study.budget._run",
    "histostudy.study.error_budget_notebook": "histostudy.study.budget._notebook",
    "histostudy.study.error_budget_summary": "histostudy.study.budget._summary",
    "histostudy.study.lab_errors": "histostudy.study.budget._sources",
    "histostudy.imaging.anatomy_csg": "histostudy.imaging.anatomy._csg",
    "histostudy.imaging.anatomy_params": "histostudy.imaging.anatomy._params",
    "histostudy.imaging.anatomy_rays": "histostudy.imaging.anatomy._rays",
    "histostudy.imaging.anatomy_scene": "histostudy.imaging.anatomy._scene",
    "histostudy.imaging.anatomy_shapes": "histostudy.imaging.anatomy._shapes",
    "histostudy.imaging.render_device": "histostudy.imaging.render._device",
    "histostudy.imaging.render_settings": "histostudy.imaging.render._settings",
    "histostudy.imaging.render_torch": "histostudy.imaging.render._torch",
    "histostudy.imaging.splat_kernels": "histostudy.imaging.render._splat_kernels",
    "histostudy.imaging.dicom_geometry": "histostudy.imaging.io._geometry",
    "histostudy.imaging.dicom_io": "histostudy.imaging.io._dicom",
    "histostudy.imaging.dicom_xa": "histostudy.imaging.io._xa",
    "histostudy.imaging.nifti_io": "histostudy.imaging.io._nifti",
    "histostudy.imaging.volume_io": "histostudy.imaging.io._volumes",
    "histostudy.imaging.volume_io_grid": "histostudy.imaging.io._grid",
    "histostudy.robot.controller_arm": "histostudy.robot.controller._arm",
    "histostudy.robot.controller_program": "histostudy.robot.controller._program",
    "histostudy.robot.controller_protocol": "histostudy.robot.controller._protocol",
    "histostudy.robot.controller_server": "histostudy.robot.controller._server",
    "histostudy.robot.rtde_connection": "histostudy.robot.rtde._connection",
    "histostudy.robot.rtde_units": "histostudy.robot.rtde._units",
    "histostudy.learning.training_config": "histostudy.learning.training._config",
    "histostudy.learning.training_export": "histostudy.learning.training._export",
    "histostudy.learning.training_losses": "histostudy.learning.training._losses",
    "histostudy.learning.training_teacher": "histostudy.learning.training._teacher",
    "histostudy.pose.tracker": "histostudy.pose.tracking._tracker",
    "histostudy.pose.tracking_input": "histostudy.pose.tracking._input",
    "histostudy.pose.tracking_maps": "histostudy.pose.tracking._maps",
    "histostudy.pose.tracking_options": "histostudy.pose.tracking._options",
    "histostudy.pose.tracking_pipeline": "histostudy.pose.tracking._pipeline",
    "histostudy.pose.tracking_roi": "histostudy.pose.tracking._roi",
    "histostudy.pose.tracking_scratch": "histostudy.pose.tracking._scratch",
    "histostudy.pose.tracking_warm": "histostudy.pose.tracking._warm",
    "histostudy.pose.cost_kernels": "histostudy.pose.cost._kernels",
    "histostudy.pose.cost_reference": "histostudy.pose.cost._reference",
}


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec):
        public = ".".join(part for part in self.new.split(".") if not part.startswith("_"))
        warnings.warn(f"{spec.name} is deprecated and goes in histostudy {MOVED_MODULES_REMOVED_IN}: import from "
                      f"{public} instead", DeprecationWarning, stacklevel=2)
        return importlib.import_module(self.new)

    def exec_module(self, module):
        # the module was executed under its new name; running it again would make a second copy
        pass


class _MovedModuleFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        new = MOVED_MODULES.get(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _AliasLoader(new))


def install() -> None:
    """Put the hook for :data:`MOVED_MODULES` on ``sys.meta_path`` (once; idempotent)."""
    if not any(isinstance(finder, _MovedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.append(_MovedModuleFinder())


def renamed_attributes(namespace: dict, renamed: dict[str, str]):
    """A module ``__getattr__`` for the names of ``renamed`` (old name -> new name, both in the
    module's ``namespace``, its ``globals()``): the old name returns the new object and warns that
    it goes in :data:`MOVED_MODULES_REMOVED_IN`; any other missing name raises AttributeError."""
    module = namespace["__name__"]

    def __getattr__(name: str):
        if name in renamed:
            warnings.warn(f"{module}.{name} is deprecated and goes in histostudy {MOVED_MODULES_REMOVED_IN}: use "
                          f"{renamed[name]} instead", DeprecationWarning, stacklevel=2)
            return namespace[renamed[name]]
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return __getattr__
