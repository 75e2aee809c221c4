"""A live loadout: the operator's commands from the terminal, the run on a live bus, the view.

:func:`run_live` feeds a :class:`~excavator_payload.runtime.loadout_bus.BusLoadout` from a live
bus and takes a queue of commands (:func:`read_commands` fills it from the terminal on its own
thread, so a silent keyboard never holds the bus): ``truck`` closes the truck being loaded (as
the button does), ``quit`` ends the shift as Ctrl-C does. :func:`live_view` draws the truck
being loaded (rich).
"""

from __future__ import annotations

import logging
import math
import queue
import time as _time

import can

from excavator_payload.runtime.can_sensor import BusLink
from excavator_payload.runtime.loadout import Truck
from excavator_payload.runtime.loadout_bus import BusLoadout

#: The terminal's commands during a live run (a key; from a pipe, a line: letter or word).
COMMANDS = {"t": "truck", "truck": "truck", "q": "quit", "quit": "quit"}
#: The live view's footer while the terminal's commands are read.
COMMAND_HELP = "t: next truck · q: end the shift (recorded) · Ctrl-C: stop"

_log = logging.getLogger(__name__)


def read_commands(stream, commands: queue.Queue, on_unknown=None, keys: bool = False) -> None:
    """Read the operator's commands from ``stream`` into ``commands`` until the stream ends or
    fails (stdin closed, redirected from nothing, not readable: then there are simply no
    commands). Run it on its own (daemon) thread: a read blocks.

    Parameters
    ----------
    stream : text file
        Where the commands come from (``sys.stdin``).
    commands : queue.Queue
        Gets ``"truck"`` or ``"quit"`` per command (:data:`COMMANDS`); ``None`` when the stream ends.
    on_unknown : callable, optional
        ``on_unknown(text)`` for a line (or key) that is no command.
    keys : bool
        One key is one command (a terminal in cbreak mode, :func:`terminal_keys`); else one
        line is (a pipe, a terminal in line mode).
    """
    try:
        for piece in (_key_presses(stream) if keys else stream):
            text = piece.strip()
            if text.lower() in COMMANDS:
                commands.put(COMMANDS[text.lower()])
            elif text and on_unknown is not None:
                on_unknown(text)
    except (OSError, ValueError, UnicodeDecodeError):  # a closed or unreadable stdin: no commands
        pass
    commands.put(None)


def _key_presses(stream):
    """One lower-case character per key pressed on ``stream`` (a terminal in cbreak mode), read
    unbuffered from its file descriptor: a buffered read would wait for a whole line."""
    import os

    fd = stream.fileno()
    while key := os.read(fd, 1):
        yield key.decode("ascii", "replace").lower()


def readable_commands(stream) -> bool:
    """Whether ``stream`` (``sys.stdin``) can give commands without harm: open, and if a terminal,
    this process is its foreground job (a background job reading its terminal is stopped by
    the shell, SIGTTIN: the bus would stop with it).

    Parameters
    ----------
    stream : text file or None
        ``sys.stdin``.
    """
    import os

    if stream is None or getattr(stream, "closed", True):
        return False
    try:
        if stream.isatty():
            fd = stream.fileno()
            return os.tcgetpgrp(fd) == os.getpgrp()
    except (OSError, ValueError, AttributeError):  # a fake stdin (tests' capture) or no job control
        return hasattr(stream, "read")
    return True


def terminal_keys(stream):
    """Put the terminal ``stream`` in cbreak mode (a key is read without Enter and not echoed
    into the live view; Ctrl-C still stops); returns the function that restores it, or None
    when ``stream`` is no terminal (then commands are lines).

    Parameters
    ----------
    stream : text file
        ``sys.stdin``.
    """
    try:
        import termios
        import tty

        if stream is None or not stream.isatty() or not readable_commands(stream):
            return None
        fd = stream.fileno()
        saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)
    except (ImportError, OSError, ValueError, AttributeError):  # Windows, a closed or fake stdin
        return None
    return lambda: termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def run_live(bus: can.BusABC, loadout: BusLoadout, stop, clock=_time.monotonic, on_tick=None,
             error_pause: float = 0.1, commands: queue.Queue | None = None, bus_factory=None,
             name: str = "") -> dict:
    """Read ``bus`` and send what ``loadout`` says until ``stop`` (a ``threading.Event``) is set;
    then the last truck is closed (and its total sent).

    Parameters
    ----------
    bus : can.BusABC
        The open bus (frames are read from and sent to it).
    loadout : BusLoadout
        Made with ``send=True``.
    stop : threading.Event
        Set to stop.
    clock : callable
        The receiver's clock, s (time-outs: a partial sample, a silent sensor, a truck gone).
    on_tick : callable, optional
        Called once per sample period (the live view's refresh).
    error_pause : float
        Pause after a failing receive, s.
    commands : queue.Queue, optional
        The operator's commands (:func:`read_commands`), taken without waiting once per sample
        period: ``"truck"`` closes the truck (:meth:`BusLoadout.new_truck`), ``"quit"`` stops.
    bus_factory : callable, optional
        Opens the bus again after it was lost (see :class:`~excavator_payload.runtime.can_sensor.BusLink`).
    name : str, optional
        What the log lines call the bus (``IFACE:CHANNEL``).

    Returns
    -------
    dict
        ``published`` frames, ``bus_errors`` (a failing ``recv`` or ``send``, error frames:
        logged and counted, never fatal), ``truck_commands`` (trucks closed by a command) and the
        outages: ``bus_lost``, ``bus_lost_seconds``, ``bus_off``, ``bus_off_seconds``.
    """
    counters = {"published": 0, "bus_errors": 0, "truck_commands": 0}
    link = BusLink(bus, counters, stop, bus_factory, name, error_pause, logger=_log)
    period = loadout.sensor.period
    next_tick = clock() + period

    def publish(frames):
        for frame in frames:
            link.send(frame)

    try:
        while not stop.is_set():
            message = link.recv(max(0.0, min(next_tick - clock(), period)))
            if link.lost:  # nothing is fed or published until the bus is back
                next_tick = clock() + period
                continue
            if message is not None:
                if message.is_error_frame:
                    link.error_frame(message)
                else:
                    publish(loadout.feed(message, clock()))
            while commands is not None:
                try:
                    command = commands.get_nowait()
                except queue.Empty:
                    break
                if command == "truck":
                    before = len(loadout.trucks)
                    publish(loadout.new_truck())
                    counters["truck_commands"] += len(loadout.trucks) - before  # none loaded: no truck
                elif command == "quit":
                    stop.set()
            now = clock()
            if now >= next_tick:
                last = loadout.sensor.last_sample_received
                if last is None or now - last > period:
                    publish(loadout.poll(now))
                next_tick = max(next_tick + period, now)
                if on_tick is not None:
                    on_tick()
    finally:
        publish(loadout.new_truck())
        loadout.finish()
        link.close()
    return counters


def advice(truck: Truck) -> str:
    """What is left for the truck and what the last pass should carry (empty without a target).

    Parameters
    ----------
    truck : Truck
        The truck being loaded.
    """
    if truck.target is None:
        return ""
    left = truck.target - truck.total
    if left <= 0:
        return f"target reached ({-left:,.0f} kg over)"
    weights = [p.weight for p in truck.passes if p.weight is not None]
    if not weights:
        return f"{left:,.0f} kg to load"
    bucket = max(weights)
    if left <= bucket:
        return f"{left:,.0f} kg left: the last pass should carry {left:,.0f} kg"
    n = math.ceil(left / bucket)
    return f"{left:,.0f} kg left: about {n} passes of {left / n:,.0f} kg"


def live_view(loadout: BusLoadout, footer: str = ""):
    """The cab's view (rich): the truck being loaded (its passes, running total against the
    target, what the last pass should carry), the current estimate, a failing record, a unit
    guard's finding and active sensor faults in red, the trucks done, and ``footer`` (the operator's keys).

    Parameters
    ----------
    loadout : BusLoadout
        The shift being followed.
    footer : str, optional
        The last line, dimmed (:data:`COMMAND_HELP` while the terminal's commands are read).
    """
    from rich.console import Group
    from rich.text import Text

    from excavator_payload.runtime.loadout import truck_table

    parts = []
    truck = loadout.current
    last = loadout.sensor.last_output
    guard = loadout.guard
    failing = getattr(loadout.record, "failure", None)  # a KeptRecord that cannot write
    if failing:
        parts.append(Text(f"NOT RECORDED: {failing}; the trucks are kept {loadout.record.kept_where()}",
                          style="bold red"))
    if guard is not None and guard.flagged:
        parts.append(Text(f"NOT WEIGHING: {guard.message(loadout.guard_source)}", style="bold red"))
    elif last is not None:
        parts.append(Text(f"bucket {last.estimate:,.0f} kg ± {last.sigma:.1f} ({last.status})"
                          if math.isfinite(last.estimate) else f"bucket: no estimate ({last.status})"))
    if truck is not None:
        parts.append(truck_table(truck))
        parts.append(Text(f"truck {truck.truck}: {len(truck.passes)} passes, {truck.total:,.0f} kg"
                          + (f" of {truck.target:,.0f} kg; {advice(truck)}" if truck.target is not None else "")))
    else:
        parts.append(Text("waiting for the next truck's first pass"))
    active = [e for e in loadout.sensor.dm1.episodes if not math.isfinite(e.end)]
    for e in active:
        parts.append(Text(f"sensor fault: DM1 SPN {e.spn} FMI {e.fmi} ({e.signal} {e.kind}) since "
                          f"{e.start:.1f} s", style="bold red"))
    if loadout.trucks:
        done = loadout.trucks
        parts.append(Text(f"{len(done)} trucks done, {sum(len(t.passes) for t in done)} passes, "
                          f"{sum(t.total for t in done):,.0f} kg"))
    if footer:
        parts.append(Text(footer, style="dim"))
    return Group(*parts)
