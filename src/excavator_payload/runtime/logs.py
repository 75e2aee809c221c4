"""CAN log files in: every format ``can-replay`` reads, and what a log holds.

Formats, by suffix (any case) and, for text logs, by their first frame line:

* python-can's: ``.asc`` (Vector), ``.blf``, ``.csv``, ``.trc`` (PEAK), ``.log`` (candump ``-l``);
* ``.mf4`` (ASAM MDF 4, a CANedge logger's format): the ``CAN_DataFrame`` channel groups of bus
  logging, read through python-can with ``asammdf``;
* candump's *screen* format (``  can0  18FF0121   [8]  01 02 …``, what ``candump can0 > x.txt``
  saves), in ``.log`` or ``.txt``: with ``-t a`` / ``-t A`` / ``-t z`` / ``-t d`` timestamps
  (absolute, date, zero-based, delta), the ``-x`` direction columns and ``-a`` ASCII tails.
  Without timestamps it has no time to weigh by: one line says how to record one that does.
* ``.txt`` holding candump ``-l`` lines.

:class:`LogSummary` counts what went by (ids, PGNs and source addresses, rates) so that a log
in which nothing matches the sensor's DBC gets a one-line account of what it does hold.
"""

from __future__ import annotations

import io
import logging
import math
import re
import struct
import zlib
from datetime import datetime
from pathlib import Path
from typing import Iterator

import can
from can.io.blf import BLFParseError

from excavator_payload.errors import DatasetError

#: Log formats ``can-replay`` reads (by file suffix, any case).
READ_SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc", ".mf4", ".txt")
#: CANedge's compressed / encrypted MDF files: not MDF until its tools have unpacked them.
PACKED_MDF = (".mfc", ".mfe", ".mfm")

#: What python-can's readers raise on a file that is not the format its suffix says: a
#: truncated or foreign BLF raises struct.error, zlib.error or BLFParseError, an unsupported TRC
#: version NotImplementedError (all of them escaped as an internal error before).
UNREADABLE_LOG = (ValueError, OSError, KeyError, IndexError, TypeError, EOFError, NotImplementedError,
                  AttributeError, struct.error, zlib.error, BLFParseError, can.CanError)
try:  # a file named .mf4 that is no MDF ("magic header is b'garbage'") was an internal error
    from asammdf.blocks.utils import MdfException

    UNREADABLE_LOG += (MdfException,)
except ImportError:  # asammdf is optional to python-can; without it .mf4 fails as an ImportError
    pass

_CANUTILS = re.compile(r"^\s*\(\s*-?[0-9.]+\s*\)\s+\S+\s+[0-9A-Fa-f]+#")
#: A whole ``candump -l`` line: (time) interface id#data, id##flags+data (CAN FD) or id#R (remote).
_CANUTILS_LINE = re.compile(r"^\(\s*-?[0-9]+(?:\.[0-9]+)?\s*\)\s+\S+\s+[0-9A-Fa-f]{1,8}"
                            r"(?:#(?:[0-9A-Fa-f]{2})*|#R[0-9A-Fa-f]?|##[0-9A-Fa-f](?:[0-9A-Fa-f]{2})*)(?:\s+[RT])?$")
_SCREEN = re.compile(
    r"^\s*(?:\((?P<ts>[^)]*)\)\s+)?(?P<ifc>\S+)\s+(?:(?:RX|TX)\s+\S+\s+\S+\s+)?"
    r"(?P<id>[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})\s+\[(?P<len>\d{1,2})\]"
    r"(?P<data>(?:\s+[0-9A-Fa-f]{2}(?![0-9A-Za-z]))*)(?P<rest>.*)$")


def check_suffix(path: Path, suffixes=READ_SUFFIXES) -> None:
    """Raise :class:`DatasetError` unless ``path`` ends in one of ``suffixes`` (any case).

    Parameters
    ----------
    path : Path
        The log file.
    suffixes : sequence of str, optional
        Accepted suffixes, lower case with the dot (default :data:`READ_SUFFIXES`).
    """
    suffix = path.suffix.lower()
    if suffix in PACKED_MDF:
        raise DatasetError(f"'{path}': a CANedge compressed or encrypted log ({path.suffix}); unpack it "
                           "to .MF4 with the CANedge tools (mdf2finalized / its decoders) first")
    if suffix not in suffixes:
        raise DatasetError(f"'{path}': unknown CAN log format {path.suffix!r}; use one of "
                           f"{', '.join(suffixes)}")


class _SkippedRecords(logging.Handler):
    """Counts the records python-can's readers skip with a logged warning (a TRC or ASC line
    they cannot parse): they were printed on stderr, breaking the one-line rule, and the lines
    were lost without a count."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1


def _first_frame_line(path: Path) -> str | None:
    with open(path, encoding="utf-8", errors="replace") as f:
        for k, line in enumerate(f):
            if line.strip() and not line.lstrip().startswith("#"):
                return line
            if k > 1000:
                break
    return None


def text_format(path: Path) -> str:
    """``canutils`` (candump ``-l``), ``screen`` (candump's default) or ``unknown``, by the first
    frame line of a text log.

    Parameters
    ----------
    path : Path
        A ``.log`` or ``.txt`` CAN log.

    Returns
    -------
    str
        One of ``canutils``, ``screen``, ``unknown``, or ``empty`` when it has no frame line.
    """
    line = _first_frame_line(path)
    if line is None:
        return "empty"
    if _CANUTILS.match(line):
        return "canutils"
    if _SCREEN.match(line):
        return "screen"
    return "unknown"


def read_frames(path: str | Path, skipped: list[int] | None = None,
                ending: list[str] | None = None) -> Iterator[can.Message]:
    """Iterate the frames of a CAN log (see the module docstring), one clear line on errors.

    ``skipped``, if given (a list ``[n]``), has the records the reader could not parse and
    skipped added to ``n``. A log that ends early (:func:`log_end`: a BLF whose last container
    is cut, an ASC without its ``End TriggerBlock``, a text log cut mid-line) is read up to the
    cut (a cut last line is not read: its frame would be partial) and ``ending``, if given, gets
    the one line that says so, how many frames were read and where they stop.

    Parameters
    ----------
    path : str or Path
        The log file; its suffix says the format.
    skipped : list of int, optional
        A one-element counter ``[n]`` the unparsable records are added to.
    ending : list of str, optional
        Gets one line when the log ends early (nothing when it is whole).

    Raises
    ------
    DatasetError
        A folder, a missing file, an unknown or unreadable format.
    """
    count = [0, math.inf, -math.inf]  # frames, first and last finite timestamp
    skipped = skipped if skipped is not None else [0]
    for message in _without_clock_glitches(_read_frames(Path(path), skipped), skipped, Path(path)):
        count[0] += 1
        t = float(message.timestamp)
        if math.isfinite(t):
            count[1], count[2] = min(count[1], t), max(count[2], t)
        yield message
    if ending is not None:
        why = log_end(Path(path))
        if why:
            span = count[2] - count[1] if count[0] and math.isfinite(count[1]) else 0.0
            ending.append(f"CAN log '{path}' ends early ({why}): {count[0]} frames over {span:.4g} s were read "
                          "and are weighed, the rest of the recording is missing")


#: s, a frame this far ahead of the one before it and of the one after it carries a glitched
#: timestamp (a logger's clock read wrong for one frame), not a new recording.
CLOCK_GLITCH = 10.0
#: More glitched frames than this share of a log's frames are two clocks, not glitches.
CLOCK_GLITCH_SHARE = 1e-3


def _without_clock_glitches(frames: Iterator[can.Message], skipped: list[int],
                            path: Path) -> Iterator[can.Message]:
    """``frames`` without the single frames whose timestamp jumps more than :data:`CLOCK_GLITCH`
    ahead of both neighbours (counted in ``skipped``, as an unreadable record). One such frame
    (a timestamp 10⁹ s ahead) made every later frame "go back" and the whole log was refused
    ("its time goes back between 27995 of 55992 sensor frames"); a new recording after a gap
    jumps ahead and stays there, and is kept. Many such frames are no glitch but a shuffled log
    or two clocks interleaved (:data:`CLOCK_GLITCH_SHARE`): refused, as before, in one line."""
    last, held, frames_seen, glitches = None, None, 0, 0
    for message in frames:
        frames_seen += 1
        t = float(message.timestamp)
        if held is not None:
            if math.isfinite(t) and t < float(held.timestamp) - CLOCK_GLITCH:
                glitches += 1  # the held frame was alone ahead: its time is wrong
                skipped[0] += 1
            else:
                last = float(held.timestamp)
                yield held
            held = None
        if math.isfinite(t) and (last is None or t > last + CLOCK_GLITCH):
            held = message  # the first frame, or a jump ahead: a new recording, or one glitched frame
            continue
        if math.isfinite(t):
            last = t
        yield message
    if held is not None:
        yield held
    if glitches > 3 and glitches > CLOCK_GLITCH_SHARE * frames_seen:
        raise DatasetError(f"CAN log '{path}': {glitches} of its {frames_seen} frames have a timestamp more than "
                           f"{CLOCK_GLITCH:g} s ahead of the frames before and after them: frames out of order "
                           "(a log merged and never sorted? sort it by timestamp), or two clocks interleaved "
                           "(channels logged with different time bases: give a log on one clock)")


def _read_frames(path: Path, skipped: list[int] | None) -> Iterator[can.Message]:
    if path.is_dir():
        raise DatasetError(f"CAN log '{path}' is a folder, not a log file")
    if not path.is_file():
        from excavator_payload.textfiles import not_a_file

        raise DatasetError(not_a_file(path, "CAN log"))
    check_suffix(path)
    suffix = path.suffix.lower()
    skipped = skipped if skipped is not None else [0]
    if suffix in (".log", ".txt"):
        kind = text_format(path)
        if kind == "screen":
            yield from _read_screen(path, skipped)
            return
        if kind == "unknown":
            line = (_first_frame_line(path) or "").strip()
            raise DatasetError(f"CAN log '{path}': not a candump log (neither `candump -l` lines "
                               f"'(1436509052.249713) can0 18FF0121#0102…' nor candump's screen format "
                               f"'can0  18FF0121   [8]  01 02 …'); its first line is {line[:60]!r}")
        if kind == "empty":
            return
        if suffix == ".txt":
            yield from _python_can(path, skipped, can.io.canutils.CanutilsLogReader)
            return
    if suffix == ".csv":
        yield from _csv_hex_data(_python_can(path, skipped, can.LogReader), path)
        return
    yield from _python_can(path, skipped, can.LogReader)


def _csv_hex_data(frames: Iterator[can.Message], path: Path) -> Iterator[can.Message]:
    """python-can's CSV frames, with a ``data`` column written in hex (as other tools write it)
    read as hex: python-can reads the column as base64 only, and hex text is valid base64, so
    every 8-byte frame decoded as 12 bytes of garbage and the log was refused as "out of the
    DBC's ranges". A frame whose data is not its DLC's length both ways is refused in one line."""
    import base64

    for number, message in enumerate(frames, 2):
        if len(message.data) != message.dlc and not message.is_remote_frame:
            text = base64.b64encode(bytes(message.data)).decode("ascii").rstrip("=")
            try:
                data = bytes.fromhex(text)
            except ValueError:
                data = None
            if data is None or len(data) != message.dlc:
                raise DatasetError(f"CAN log '{path}': line {number}'s data ({len(message.data)} bytes as base64) "
                                   f"does not match its dlc {message.dlc}: the data column must be base64 "
                                   "(python-can's CSV) or hex")
            message.data = bytearray(data)
        yield message


def _bad_text_line(path: Path) -> str | None:
    """The first line of a ``candump -l`` log that is no frame line, as a sentence (python-can
    said only "not enough values to unpack"); None if every line looks like one."""
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f, 1):
            text = line.strip()
            if text and not text.startswith("#") and not _CANUTILS_LINE.match(text):
                return (f"line {number} is not a `candump -l` frame line: {text[:60]!r} (a log cut short or "
                        "edited by hand? delete that line)")
    return None


def _collect_quietly() -> None:
    """Collect the garbage a failed reader left without asammdf's complaints: an MDF4 object
    whose constructor failed on a truncated file prints "Exception ignored in MDF4.__del__" and
    a traceback when it is collected, breaking the one-line rule (even in a later, good run)."""
    import gc
    import sys

    previous = sys.unraisablehook

    def hook(unraisable):
        if not str(getattr(unraisable.object, "__module__", "") or "").startswith("asammdf"):
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        gc.collect()
    finally:
        sys.unraisablehook = previous


def _python_can(path: Path, skipped: list[int], reader) -> Iterator[can.Message]:
    readers = logging.getLogger("can.io")
    handler = _SkippedRecords()
    propagate = readers.propagate
    readers.addHandler(handler)
    readers.propagate = False
    try:
        cut = _text_cut(path) if path.suffix.lower() in TEXT_SUFFIXES else None
        if cut is None:
            yield from reader(str(path))
        else:  # a line cut mid-way parses as a partial frame or fails: the whole lines only
            import locale

            with open(path, "rb") as raw:
                text = io.TextIOWrapper(io.BufferedReader(_Upto(raw, cut[0])),
                                        encoding=locale.getpreferredencoding(False))
                yield from _READERS[path.suffix.lower()](text)
    except UNREADABLE_LOG as exc:
        kind = ("truncated or not a BLF file" if isinstance(exc, (struct.error, zlib.error, BLFParseError))
                else "truncated or damaged MF4 file" if path.suffix.lower() == ".mf4" and (
                    isinstance(exc, ValueError) or "exceeds the file" in str(exc))
                else type(exc).__name__)
        where = _bad_text_line(path) if path.suffix.lower() in (".log", ".txt") else None
        message = (f"CAN log '{path}': {where}" if where else
                   f"CAN log '{path}' could not be read ({kind}): {exc}")
        exc.__traceback__ = None  # the reader's frames (a half-built MDF among them) go now
        del exc
        _collect_quietly()
        raise DatasetError(message) from None
    finally:
        readers.removeHandler(handler)
        readers.propagate = propagate
        skipped[0] += handler.count


def _screen_time(text: str) -> float:
    text = text.strip()
    if "-" in text[1:] and ":" in text:  # candump -t A: (2015-07-10 08:27:32.249713)
        return datetime.strptime(text, "%Y-%m-%d %H:%M:%S.%f").timestamp()
    return float(text)


def _read_screen(path: Path, skipped: list[int]) -> Iterator[can.Message]:
    """candump's screen format. Delta timestamps (``-t d``) are told from absolute and zero-based
    ones by going back (they do, the others never): a whole log is read first to tell."""
    rows = []
    cut = _text_cut(path)
    with open(path, "rb") as raw:
        f = io.TextIOWrapper(io.BufferedReader(_Upto(raw, cut[0])) if cut else raw, encoding="utf-8",
                             errors="replace")
        for line in f:
            if not line.strip():
                continue
            m = _SCREEN.match(line)
            if m is None:
                skipped[0] += 1  # an error frame's explanation lines, a cut line
                continue
            if m.group("ts") is None:
                raise DatasetError(
                    f"CAN log '{path}': candump's screen format without timestamps ('{line.strip()[:40]}'): "
                    "nothing to weigh by in time; record with `candump -l can0` (a log file) or "
                    "`candump -ta can0 > log.txt`")
            try:
                stamp = _screen_time(m.group("ts"))
            except ValueError:
                skipped[0] += 1
                continue
            rows.append((stamp, m))
    stamps = [r[0] for r in rows]
    steps = [b - a for a, b in zip(stamps, stamps[1:])]
    if any(s < -1e-6 for s in steps) or (steps and sum(s == 0 for s in steps) > 0.9 * len(steps)):
        total, stamps = 0.0, []
        for stamp, _ in rows:
            total += stamp
            stamps.append(total)
    for stamp, (_, m) in zip(stamps, rows):
        ident = m.group("id")
        rest = m.group("rest")
        data = bytes.fromhex("".join(m.group("data").split()))
        yield can.Message(timestamp=stamp, arbitration_id=int(ident, 16), is_extended_id=len(ident) == 8,
                          data=data, channel=m.group("ifc"), is_remote_frame="remote request" in rest,
                          is_error_frame="ERRORFRAME" in rest, check=False)


# -- a log that ends early ---------------------------------------------------------------------
#: Text log formats (read line by line: a log cut mid-line ends in a partial line).
TEXT_SUFFIXES = (".asc", ".log", ".txt", ".csv", ".trc")
_READERS = {".asc": can.ASCReader, ".log": can.io.canutils.CanutilsLogReader,
            ".txt": can.io.canutils.CanutilsLogReader, ".csv": can.CSVReader, ".trc": can.TRCReader}


class _Upto(io.RawIOBase):
    """The first ``limit`` bytes of the binary file ``raw`` (a log without its cut last line)."""

    def __init__(self, raw, limit: int) -> None:
        super().__init__()
        self.raw, self.left = raw, limit

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        view = memoryview(buffer)[: max(0, self.left)]
        n = self.raw.readinto(view) if len(view) else 0
        self.left -= n
        return n


def _text_cut(path: Path) -> tuple[int, str] | None:
    """``(bytes before the cut line, the cut line)`` when a text log's last line has no line end
    (every logger ends its lines: the file was cut mid-line), else None."""
    size = path.stat().st_size
    if size == 0:
        return None
    with open(path, "rb") as f:
        f.seek(max(0, size - 4096))
        tail = f.read()
    if tail.endswith(b"\n"):
        return None
    start = tail.rfind(b"\n") + 1
    if start == 0 and size > len(tail):  # a last "line" of more than 4 KiB: no log line
        return size - len(tail), tail[:60].decode("utf-8", "replace")
    return size - len(tail) + start, tail[start:].decode("utf-8", "replace")


def log_end(path: str | Path) -> str | None:
    """Why the CAN log ``path`` ends early, or None when it ends whole (as far as its format tells).

    A BLF's objects (its compressed containers) each say their size: a last object larger than
    what is left of the file, or a file shorter than its header's size, was cut. An ASC that
    has its ``Begin Triggerblock`` ends with ``End TriggerBlock``. A text log (ASC, candump,
    CSV, TRC, candump's screen format) cut mid-line ends without a line end. A text log cut
    exactly at a line end (but for an ASC) cannot be told from a whole one. MF4: asammdf cannot
    read a cut file at all (:func:`read_frames` refuses it in one line).

    Parameters
    ----------
    path : str or Path
        The CAN log.

    Returns
    -------
    str or None
        ``"its last BLF container is cut after 812 of its 16,412 bytes"``, ``"no End TriggerBlock
        line"``, ``"its last line is cut mid-way, not read: '(0.2555'"``; None if whole.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".blf":
        return _blf_end(path)
    if suffix not in TEXT_SUFFIXES:
        return None
    cut = _text_cut(path)
    if cut is not None:
        return f"its last line is cut mid-way, not read: {cut[1].strip()[:60]!r}"
    if suffix == ".asc":
        with open(path, "rb") as f:
            head = f.read(8192).lower()
            f.seek(max(0, path.stat().st_size - 4096))
            lines = [line.strip() for line in f.read().lower().splitlines() if line.strip()]
        if b"begin triggerblock" in head and not (lines and lines[-1].startswith(b"end triggerblock")):
            return "no 'End TriggerBlock' line after its last frame: cut short"
    return None


def _blf_end(path: Path) -> str | None:
    from can.io.blf import FILE_HEADER_STRUCT, OBJ_HEADER_BASE_STRUCT

    size = path.stat().st_size
    with open(path, "rb") as f:
        data = f.read(FILE_HEADER_STRUCT.size)
        if len(data) < FILE_HEADER_STRUCT.size:
            return None  # not read at all: read_frames said why
        header = FILE_HEADER_STRUCT.unpack(data)
        position, declared = header[1], header[10]
        while position < size:
            f.seek(position)
            base = f.read(OBJ_HEADER_BASE_STRUCT.size)
            if len(base) < OBJ_HEADER_BASE_STRUCT.size:
                return f"it stops inside an object's header, at byte {size:,}"
            signature, _, _, object_size, _ = OBJ_HEADER_BASE_STRUCT.unpack(base)
            if signature != b"LOBJ" or object_size < OBJ_HEADER_BASE_STRUCT.size:
                return None  # not a cut: python-can reads or refuses it
            if position + object_size > size:
                return (f"its last BLF container is cut after {size - position:,} of its {object_size:,} "
                        f"bytes, at byte {size:,}")
            position += object_size + object_size % 4
    if declared > size:
        return f"the file has {size:,} bytes where its header says {declared:,}"
    return None


# -- what a log holds --------------------------------------------------------------------------
def pgn_of(arbitration_id: int) -> int:
    """PGN of a 29-bit J1939 id (PDU1: destination address dropped).

    Parameters
    ----------
    arbitration_id : int
        A 29-bit frame id.
    """
    pgn = (arbitration_id >> 8) & 0x3FFFF
    if ((pgn >> 8) & 0xFF) < 240:
        pgn &= 0x3FF00
    return pgn


class LogSummary:
    """Frames per id (count, first and last time) of a log, for the line that says what it holds."""

    def __init__(self) -> None:
        self.ids: dict[tuple[int, bool], list] = {}
        self.frames = 0
        self.first = math.inf
        self.last = -math.inf

    def add(self, message: can.Message) -> None:
        """Count one frame.

        Parameters
        ----------
        message : can.Message
            A frame of the log (error frames are counted, not listed by id).
        """
        self.frames += 1
        if message.is_error_frame:
            return
        t = float(message.timestamp)
        key = (int(message.arbitration_id), bool(message.is_extended_id))
        entry = self.ids.get(key)
        if entry is None:
            self.ids[key] = [1, t, t]
        else:
            entry[0] += 1
            entry[1], entry[2] = min(entry[1], t), max(entry[2], t)
        if math.isfinite(t):
            self.first, self.last = min(self.first, t), max(self.last, t)

    def describe(self, limit: int = 8) -> str:
        """``"4319 frames over 43.2 s from 12 ids: 18FF01A0 (PGN 0xFF01, SA 0xA0) 432 at 10 Hz, …"``.

        Parameters
        ----------
        limit : int, optional
            How many ids (the most frequent) are listed.
        """
        if not self.frames:
            return "no frames"
        span = self.last - self.first if math.isfinite(self.first) else 0.0
        parts = []
        for (ident, extended), (count, first, last) in sorted(self.ids.items(), key=lambda kv: -kv[1][0])[:limit]:
            name = (f"{ident:08X} (PGN 0x{pgn_of(ident):04X}, SA 0x{ident & 0xFF:02X})" if extended
                    else f"{ident:03X}")
            rate = (count - 1) / (last - first) if count > 1 and last > first else math.nan
            parts.append(f"{name} {count}" + (f" at {rate:.3g} Hz" if math.isfinite(rate) else ""))
        more = len(self.ids) - limit
        tail = f", and {more} more id(s)" if more > 0 else ""
        return (f"{self.frames} frames over {span:.4g} s from {len(self.ids)} id(s): "
                + ", ".join(parts) + tail)
