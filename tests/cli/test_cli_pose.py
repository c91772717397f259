"""The ``histostudy`` command's lab subcommands: ``pose`` on a DICOM XA pair as a C-arm writes it
(uncompressed, and compressed as a C-arm may send it), ``report`` rebuilt from a folder,
``--version``; and an object that is not an X-ray image refused by ``pose``, ``calibrate`` and the
receiver of ``listen`` with the same reason. (``reproduce`` is tested in tests/reporting.)"""

import json
import re
import shutil
import subprocess
from types import SimpleNamespace

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


CT_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.2"
#: What every reader of the lab's frames says of an object stored as a CT image.
NOT_X_RAY = (f"SOP class {CT_IMAGE_STORAGE} (CT Image Storage) is not an X-ray angiographic or RF image; this reader "
             "takes X-Ray Angiographic Image Storage, Enhanced XA Image Storage, X-Ray Radiofluoroscopic Image Storage")


def test_xa_pixels_stored_as_a_ct_image_are_refused_alike_by_pose_calibrate_and_listen(xa_pair, tmp_path, capsys):
    import pydicom

    from histostudy.imaging import load_views
    from histostudy.imaging.io import XRayObjectRejected
    from histostudy.lab.xray_objects import read_c_store

    station = tmp_path / "station"
    station.mkdir()
    for plane in "AB":
        ds = pydicom.dcmread(xa_pair / f"{plane}.dcm")
        ds.SOPClassUID = ds.file_meta.MediaStorageSOPClassUID = CT_IMAGE_STORAGE  # the XA pixels, as a CT image
        ds.save_as(station / f"{plane}.dcm", enforce_file_format=True)
    frames = [str(station / "A.dcm"), str(station / "B.dcm")]
    out = tmp_path / "pose.json"
    # histostudy pose, the views from the tags (View.from_dicom) or from a views file (load_frame)
    for views in ([], ["--views", str(xa_pair / "views.json")]):
        assert main(["pose", *frames, *views, "--output", str(out)]) == 2
        assert capsys.readouterr().err.rstrip("\n").endswith(f"A.dcm': {NOT_X_RAY}" if views else f"A.dcm: {NOT_X_RAY}")
    assert not out.exists()
    # histostudy calibrate on a station folder holding them
    flanges = tmp_path / "flanges.json"
    flanges.write_text(json.dumps({"T_base_flange": [np.eye(4).tolist()]}))
    assert main(["calibrate", str(station), "--flange-poses", str(flanges), "--output", str(tmp_path / "c.json")]) == 2
    assert capsys.readouterr().err.rstrip("\n").endswith(f"A.dcm: {NOT_X_RAY}")
    # histostudy listen: the receiver's C-STORE handler reads the request with read_c_store
    ds = pydicom.dcmread(station / "A.dcm")
    event = SimpleNamespace(request=SimpleNamespace(AffectedSOPClassUID=CT_IMAGE_STORAGE,
                                                    AffectedSOPInstanceUID=ds.SOPInstanceUID),
                            dataset=ds, file_meta=ds.file_meta)
    with pytest.raises(XRayObjectRejected) as refused:
        read_c_store(event, load_views(xa_pair / "views.json"))
    assert refused.value.reason == NOT_X_RAY and refused.value.status == 0x0122


def _compressed_pair(xa_pair, folder, syntax):
    """A.dcm and B.dcm of ``xa_pair`` in ``syntax``: JPEG-LS near-lossless (NEAR 2) by DCMTK's
    dcmcjpls or pydicom's encoder, RLE by DCMTK's dcmcrle or pydicom's; None where neither is here."""
    import pydicom
    from pydicom.pixels import get_encoder

    folder.mkdir()
    tool = {"1.2.840.10008.1.2.4.81": ["dcmcjpls", "+en", "+md", "2"], "1.2.840.10008.1.2.5": ["dcmcrle"]}[syntax]
    for plane in "AB":
        src, dst = xa_pair / f"{plane}.dcm", folder / f"{plane}.dcm"
        if shutil.which(tool[0]):
            subprocess.run([*tool, str(src), str(dst)], check=True, capture_output=True)
        elif get_encoder(syntax).is_available:
            ds = pydicom.dcmread(src)
            ds.compress(syntax, **({"jls_error": 2} if syntax.endswith(".81") else {}))
            ds.save_as(dst, enforce_file_format=True)
        else:
            return None
        assert str(pydicom.dcmread(dst, stop_before_pixels=True).file_meta.TransferSyntaxUID) == syntax
    return [str(folder / "A.dcm"), str(folder / "B.dcm")]


@pytest.mark.slow
def test_a_losslessly_compressed_pair_gets_the_pose_of_the_uncompressed_one(xa_pair, tmp_path):
    def pose(frames, name):
        out = tmp_path / f"{name}.json"
        assert main(["pose", *frames, "--output", str(out)]) == 0
        return json.loads(out.read_text())

    uncompressed = pose([str(xa_pair / "A.dcm"), str(xa_pair / "B.dcm")], "uncompressed")
    # RLE (lossless): the same pixels, so the same pose to the last bit
    rle = pose(_compressed_pair(xa_pair, tmp_path / "rle", "1.2.840.10008.1.2.5"), "rle")
    np.testing.assert_array_equal(rle["T_carm_transducer"], uncompressed["T_carm_transducer"])


def test_a_near_lossless_pair_is_refused_before_its_pose(xa_pair, tmp_path, capsys):
    """Its counts within 2 of 4095, but posed it moved the focal point by about 13 mm (the verdict
    refused it): lossy pixels are refused by name instead."""
    frames = _compressed_pair(xa_pair, tmp_path / "near", "1.2.840.10008.1.2.4.81")
    if frames is None:
        pytest.skip("no JPEG-LS encoder here (DCMTK's dcmcjpls or pyjpegls)")
    assert main(["pose", *frames, "--output", str(tmp_path / "p.json")]) == 2
    assert re.search(r"A\.dcm': lossy pixels are refused: its (LossyImageCompression \(0028,2110\) is 01|JPEG-LS "
                     r"stream is near-lossless \(NEAR 2\))", capsys.readouterr().err)
