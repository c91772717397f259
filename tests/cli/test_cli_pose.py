"""The ``histostudy`` command's lab subcommands: ``pose`` on a DICOM XA pair as a C-arm writes it,
``report`` rebuilt from a folder, ``--version``. (``reproduce`` is tested in tests/reporting.)"""

import json

import numpy as np
import pytest

from histostudy import __version__
from histostudy.cli import main
from histostudy.imaging import default_biplane, random_background, render_frame, save_views
from histostudy.transducer import TransducerModel, pose_facing


def write_xa(path, view, intensities):
    """A single-frame XA object with the view's geometry tags and 12-bit intensities."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian

    ds = Dataset()
    ds.file_meta = FileMetaDataset()
    ds.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds.SOPClassUID, ds.SOPInstanceUID = "1.2.840.10008.5.1.4.1.1.12.1", f"1.2.3.{len(view.name)}.{ord(view.name[0])}"
    ds.file_meta.MediaStorageSOPClassUID, ds.file_meta.MediaStorageSOPInstanceUID = ds.SOPClassUID, ds.SOPInstanceUID
    g = view.gantry
    ds.Modality = "XA"
    ds.PositionerPrimaryAngle, ds.PositionerSecondaryAngle = g["primary_deg"], g["secondary_deg"]
    ds.DistanceSourceToPatient, ds.DistanceSourceToDetector = g["source_isocenter_mm"], g["source_detector_mm"]
    ds.ImagerPixelSpacing = [view.pixel_mm, view.pixel_mm]
    ds.Rows, ds.Columns = view.shape
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 12, 11, 0
    ds.PixelData = intensities.astype(np.uint16).tobytes()
    ds.save_as(path, enforce_file_format=True)


@pytest.fixture(scope="module")
def xa_pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lab")
    rng = np.random.default_rng(1)
    model = TransducerModel.build(spacing_mm=0.25)
    scene = random_background(np.random.default_rng(2), "phantom")
    views = default_biplane()
    for view in views:
        frame = render_frame(model, pose_facing(), view, rng=rng, background=scene)
        write_xa(folder / f"{view.name}.dcm", view, np.clip(np.round(4095 * np.exp(-frame.image)), 0, 4095))
    save_views(folder / "views.json", views)
    return folder


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"histostudy {__version__}"


@pytest.mark.slow
def test_pose_on_a_dicom_xa_pair_finds_the_true_focal_point(xa_pair, capsys):
    out = xa_pair / "pose.json"
    code = main(["pose", str(xa_pair / "A.dcm"), str(xa_pair / "B.dcm"), "--output", str(out)])
    record = json.loads(out.read_text())
    assert code == 0 and record["accepted"] and "accepted" in capsys.readouterr().out
    assert np.linalg.norm(np.array(record["focal_point_mm"]) - pose_facing()[:3, 3]) < 1.0  # the true pose
    # the same frames with the views from a views file give the same pose
    again = xa_pair / "pose_views.json"
    assert main(["pose", str(xa_pair / "A.dcm"), str(xa_pair / "B.dcm"), "--views", str(xa_pair / "views.json"),
                 "--output", str(again)]) == 0
    np.testing.assert_allclose(json.loads(again.read_text())["T_carm_transducer"], record["T_carm_transducer"],
                               atol=1e-6)


def test_pose_refuses_files_without_geometry_or_missing(xa_pair, tmp_path, capsys):
    np.save(tmp_path / "A.npy", np.zeros((960, 1240)))
    assert main(["pose", str(tmp_path / "A.npy"), "--output", str(tmp_path / "p.json")]) == 2
    assert "carries no geometry" in capsys.readouterr().err
    assert main(["pose", str(xa_pair / "A.dcm"), str(tmp_path / "C.dcm"), "--output", str(tmp_path / "p.json")]) == 2
    assert not (tmp_path / "p.json").exists()


def test_report_is_rebuilt_from_a_folder_or_refused(tmp_path, capsys):
    assert main(["report", "--output", str(tmp_path)]) == 2
    assert "no readable run.json" in capsys.readouterr().err
    (tmp_path / "run.json").write_text(json.dumps({"profile": "smoke", "seed": 1, "notebooks": [], "failure": None}))
    assert main(["report", "--output", str(tmp_path)]) == 0
    assert (tmp_path / "REPORT.md").exists() and (tmp_path / "report.html").exists()
