"""What every command shares with the terminal (histostudy/cli/console.py): results as JSON on
stdout, talk on stderr at the level -q/-v ask for, progress only on a terminal, and each
subcommand's --help with a description and an example. And ``histostudy send`` (storescu's job)
against a bare Storage SCP."""

import io
import json
import logging
import sys

import numpy as np
import pytest
from pynetdicom import AE, evt

from histostudy.cli import build_parser, main
from histostudy.cli.console import Steps
from histostudy.imaging import default_biplane, write_xa
from histostudy.imaging.io._xa import XA_SOP_CLASS_UID


def subcommands():
    return next(a for a in build_parser()._actions if a.choices and "pose" in a.choices).choices


@pytest.mark.parametrize("name", sorted(subcommands()))
def test_every_subcommand_describes_itself_with_an_example(name):
    parser = subcommands()[name]
    text = parser.format_help()
    assert parser.description and len(parser.description) > 60, f"{name}: no description"
    example = text.split("example:\n", 1)[1]
    assert example.strip().startswith(f"histostudy {name}"), f"{name}: no example of itself"
    assert {"-q", "--quiet", "-v", "--verbose", "--version"} <= {s for a in parser._actions for s in a.option_strings}


@pytest.mark.parametrize("flags, own, library", [([], logging.INFO, logging.WARNING),
                                                  (["-q"], logging.ERROR, logging.ERROR),
                                                  (["-v"], logging.DEBUG, logging.INFO),
                                                  (["-vv"], logging.DEBUG, logging.DEBUG)])
def test_quiet_and_verbose_set_the_levels_of_the_commands_and_of_the_library(flags, own, library, capsys):
    assert main(["profiles", *flags]) == 0
    assert logging.getLogger("histostudy.cli").getEffectiveLevel() == own
    assert logging.getLogger("histostudy.pose").getEffectiveLevel() == library
    handlers = [h for h in logging.getLogger("histostudy").handlers if h.get_name() == "histostudy-cli-stderr"]
    assert len(handlers) == 1  # main() called again replaces its handler, it does not add one
    with pytest.raises(SystemExit) as done:
        main(["profiles", "-q", "-v"])
    assert done.value.code == 2 and "not allowed with" in capsys.readouterr().err


def test_progress_shows_each_step_on_a_terminal_and_nothing_otherwise(monkeypatch):
    terminal = io.StringIO()
    monkeypatch.setattr(sys, "stderr", terminal)
    with Steps(2, enabled=True, label="calibrate: stations") as steps:
        steps.step("calibration/station_0")
        steps.step("calibration/station_1")
    shown = terminal.getvalue()
    assert "calibrate: stations" in shown and "station_0" in shown and "station_1" in shown
    quiet = io.StringIO()
    monkeypatch.setattr(sys, "stderr", quiet)
    with Steps(2, enabled=False, label="x") as steps:
        steps.step("a")
    assert quiet.getvalue() == ""


@pytest.fixture
def scp():
    """A Storage SCP on a free port that stores XA frames and refuses the object whose
    InstanceNumber is 99 (status 0xA700, out of resources)."""
    stored = []

    def on_store(event):
        if int(event.dataset.get("InstanceNumber", 0)) == 99:
            return 0xA700
        stored.append(event.dataset.SOPInstanceUID)
        return 0x0000

    ae = AE(ae_title="HISTOSTUDY")
    ae.add_supported_context(XA_SOP_CLASS_UID, ["1.2.840.10008.1.2.1", "1.2.840.10008.1.2"])
    server = ae.start_server(("127.0.0.1", 0), block=False, evt_handlers=[(evt.EVT_C_STORE, on_store)])
    yield server.server_address[1], stored
    server.shutdown()


@pytest.fixture
def xa_files(tmp_path):
    views = default_biplane(shape=(16, 20), pixel_mm=18.0)
    counts = np.random.default_rng(0).integers(100, 4000, size=views[0].shape).astype(np.uint16)
    return [str(write_xa(tmp_path / f"{v.name}.dcm", v, counts, uid_seed=f"send-{v.name}")) for v in views]


def test_send_stores_the_files_and_prints_their_statuses_as_json(scp, xa_files, capsys):
    port, stored = scp
    assert main(["send", "127.0.0.1", str(port), *xa_files]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["statuses"] == [0, 0] and summary["n_stored"] == 2 and len(stored) == 2
    assert "sent 2 of 2 objects" in captured.err
    assert main(["send", "-q", "127.0.0.1", str(port), *xa_files]) == 0
    assert capsys.readouterr().err == ""


def test_send_exits_1_on_a_refused_object_and_2_on_a_missing_file(scp, xa_files, tmp_path, capsys):
    import pydicom

    port, _ = scp
    ds = pydicom.dcmread(xa_files[0])
    ds.InstanceNumber = 99
    refused = tmp_path / "refused.dcm"
    ds.save_as(refused)
    assert main(["send", "127.0.0.1", str(port), xa_files[1], str(refused)]) == 1
    captured = capsys.readouterr()
    assert json.loads(captured.out)["statuses"] == [0, 0xA700] and "not stored: " + str(refused) in captured.err
    assert main(["send", "127.0.0.1", str(port), str(tmp_path / "none.dcm")]) == 2
    captured = capsys.readouterr()
    assert "no such file: " in captured.err
    # refused or not, stdout holds the command's one summary line
    assert json.loads(captured.out) == {"command": "send", "exit_code": 2, "refused": False, "bad_input": True,
                                        "error": f"no such file: {str(tmp_path / 'none.dcm')!r}"}


def test_send_waits_for_a_receiver_only_as_long_as_asked(xa_files, capsys):
    import socket
    import time

    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    t0 = time.monotonic()
    assert main(["send", "127.0.0.1", str(port), *xa_files, "--wait-s", "1"]) == 1
    assert 1.0 <= time.monotonic() - t0 < 10
    assert f"nothing listens on 127.0.0.1:{port}" in capsys.readouterr().err
