"""CAN logs cut short or edited by hand: one line that says where, and nothing printed by the
readers' own leftovers (asammdf's "Exception ignored in MDF4.__del__" traceback)."""

import gc
import sys

import can
import pytest

from excavator_payload.errors import DatasetError
from excavator_payload.runtime.logs import read_frames


def _frames(n=200):
    return [can.Message(timestamp=0.01 * k, arbitration_id=0x18FF00A0, is_extended_id=True,
                        data=bytes([k % 256] * 8)) for k in range(n)]


@pytest.mark.parametrize("bad, line", [
    ("garbage here", "'garbage here'"),
    ("(1.000000) can1 ZZZ#00", "'(1.000000) can1 ZZZ#00'"),
    ("(0.2555", "'(0.2555'"),  # the logger lost power mid-line
])
def test_a_bad_candump_line_is_named_with_its_number(tmp_path, bad, line):
    good = [f"({0.01 * k:.6f}) can0 18FF00A0#{k % 256:02X}00000000000000" for k in range(50)]
    path = tmp_path / "x.log"
    path.write_text("\n".join(good[:20] + [bad] + good[20:]) + "\n")
    with pytest.raises(DatasetError, match=r"line 21 is not a `candump -l` frame line: " + line.replace("(", r"\(")
                       .replace(")", r"\)").replace(".", r"\.")):
        list(read_frames(path))


def test_candump_fd_and_remote_frames_are_frame_lines(tmp_path):
    path = tmp_path / "x.log"
    path.write_text("(0.000000) can0 18FF00A0#0102030405060708\n(0.010000) can0 18FF00A0##10102030405060708\n"
                    "(0.020000) can0 123#R\n")
    assert len(list(read_frames(path))) == 3


@pytest.mark.parametrize("keep", [300, 0.5])
def test_a_truncated_mf4_is_one_line_and_leaves_no_traceback(tmp_path, keep, monkeypatch):
    pytest.importorskip("asammdf")
    whole = tmp_path / "whole.mf4"
    with can.Logger(str(whole)) as writer:
        for m in _frames():
            writer.on_message_received(m)
    raw = whole.read_bytes()
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(raw[:keep if isinstance(keep, int) else int(len(raw) * keep)])
    complaints = []
    monkeypatch.setattr(sys, "unraisablehook", complaints.append)
    with pytest.raises(DatasetError, match="cut.mf4"):
        list(read_frames(cut))
    gc.collect()
    assert complaints == []
