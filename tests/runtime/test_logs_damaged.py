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


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log", ".csv", ".trc"])
def test_a_log_cut_anywhere_is_read_to_the_cut_and_said_to_end_early(tmp_path, suffix):
    """A log cut at 40 places (a logger that lost power, a copy that stopped): the frames read are
    the log's first frames, whole (a cut last line is not read: it parsed as a frame with part of
    its data, or refused the whole log), and one line says the log ends early, how many frames
    were read and over how long. The whole log says nothing."""
    frames = _frames(3000)
    whole = tmp_path / f"whole{suffix}"
    with can.Logger(str(whole)) as writer:
        for m in frames:
            writer.on_message_received(m)
    ending = []
    assert len(list(read_frames(whole, ending=ending))) == 3000 and ending == []
    raw = whole.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    said = 0
    for k in range(40):
        at = int(len(raw) * (0.05 + 0.9 * k / 40)) + k % 7
        cut.write_bytes(raw[:at])
        ending = []
        got = list(read_frames(cut, ending=ending))
        assert 0 < len(got) < 3000
        assert [bytes(m.data) for m in got] == [bytes(m.data) for m in frames[:len(got)]]
        if raw[:at].endswith(b"\n") and suffix != ".asc":
            continue  # cut exactly at a line's end: a whole text log looks the same
        said += 1
        assert len(ending) == 1 and "ends early" in ending[0], (at, ending)
        assert f"{len(got)} frames over" in ending[0], ending[0]
    assert said >= 38


def test_an_asc_without_its_end_triggerblock_ends_early(tmp_path):
    whole = tmp_path / "whole.asc"
    with can.Logger(str(whole)) as writer:
        for m in _frames(100):
            writer.on_message_received(m)
    lines = whole.read_text().splitlines(keepends=True)
    assert lines[-1].lower().startswith("end triggerblock")
    cut = tmp_path / "cut.asc"
    cut.write_text("".join(lines[:-1]))
    ending = []
    assert len(list(read_frames(cut, ending=ending))) == 100
    assert len(ending) == 1 and "End TriggerBlock" in ending[0] and "100 frames over 0.99 s" in ending[0]


def test_a_candump_screen_log_cut_mid_line_is_read_to_the_cut(tmp_path):
    lines = [f"({0.01 * k:.6f})  can0  18FF00A0   [8]  " + " ".join([f"{k % 256:02X}"] * 8) for k in range(50)]
    path = tmp_path / "screen.log"
    path.write_text("\n".join(lines)[:-5])  # the last line loses its last bytes
    ending = []
    got = list(read_frames(path, ending=ending))
    assert len(got) == 49 and all(len(m.data) == 8 for m in got)
    assert len(ending) == 1 and "cut mid-way" in ending[0]


@pytest.mark.parametrize("share", [0.5, 0.9, 0.99])
def test_a_truncated_mf4_is_refused_in_one_line_not_read_in_part(tmp_path, share):
    """asammdf reads no part of a cut MF4 (its data block's size is in its header): refused in
    one line that says it is truncated, never weighed as if whole."""
    pytest.importorskip("asammdf")
    whole = tmp_path / "whole.mf4"
    with can.Logger(str(whole)) as writer:
        for m in _frames(3000):
            writer.on_message_received(m)
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(whole.read_bytes()[:int(whole.stat().st_size * share)])
    with pytest.raises(DatasetError, match="truncated or damaged MF4"):
        list(read_frames(cut, ending=[]))
