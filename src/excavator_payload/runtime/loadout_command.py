"""``excavator-payload loadout``: a shift's passes and trucks weighed, shown and recorded
(:mod:`excavator_payload.runtime.loadout`), from a dataset, a CAN log or a live bus
(:mod:`excavator_payload.runtime.loadout_bus`)."""

from __future__ import annotations

import math
from pathlib import Path

import typer
from rich.console import Console

from excavator_payload.errors import DatasetError

console = Console()
#: A truck target below this share of the machine's rated payload (less than a tenth of one
#: bucket) is refused: a target in tonnes.
TARGET_SHARE = 0.1
#: The largest --target, in rated buckets: a 400 t haul truck is 80 of a 5 t bucket.
TARGET_MOST = 1000.0


def _say(line: str) -> None:
    """One line to the console, as written (paths may hold brackets)."""
    console.print(line, markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``loadout`` to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application the command is added to.
    """

    @app.command("loadout")
    def loadout(
        model: Path = typer.Option(..., "--model", help="Saved estimator folder (calibrated and zeroed).",
                                   metavar="DIR"),
        db: Path = typer.Option(..., "--db", metavar="FILE",
                                help="SQLite shift record to append to (created if missing); "
                                "rerunning the same data or log replaces its rows, never doubles them."),
        data: Path = typer.Option(None, "--data", metavar="FILE",
                                  help="Dataset of the shift (Parquet): each experiment one "
                                  "truck, or a log split at gaps of 30 s or more."),
        log: Path = typer.Option(None, "--log", metavar="FILE",
                                 help="CAN log of the shift (.mf4, .blf, .asc, .log / .txt "
                                 "candump -l or screen format with timestamps, .csv, .trc)."),
        interface: str = typer.Option(None, "--interface", metavar="NAME",
                                      help="Live bus: python-can interface (socketcan, "
                                      "pcan, kvaser, vector, virtual, …); with --channel."),
        channel: str = typer.Option(None, "--channel", metavar="NAME",
                                    help="Live bus: the interface's channel, e.g. can0."),
        dbc_file: Path = typer.Option(None, "--dbc", metavar="FILE",
                                      help="The sensors' DBC (log or bus; default: the "
                                      "generated J1939 DBC). Needs --signal-map."),
        signal_map: Path = typer.Option(None, "--signal-map", metavar="FILE", help="TOML map from our signal "
                                        "names to --dbc's signals with the factor that makes each SI (as "
                                        "can-replay); a [truck_button] table names the operator's new-truck "
                                        "button."),
        stale_tolerance: float = typer.Option(3.5, "--stale-tolerance", metavar="PERIODS",
                                              help="Log or bus: a signal older "
                                              "than its message's period times this makes the sample 'stale'."),
        truth: Path = typer.Option(None, "--truth", metavar="FILE",
                                   help="Log only: the dataset the log was recorded from; "
                                   "its experiments' true passes go to the record (truck 1 = experiment 1, …)."),
        bitrate: int = typer.Option(None, "--bitrate", metavar="BIT/S",
                                    help="Live bus: bit rate if the interface needs one."),
        duration: float = typer.Option(None, "--duration", metavar="SECONDS", help="Live bus: stop after this "
                                       "many seconds (default: until the key q, Ctrl-C or SIGTERM)."),
        target: float = typer.Option(None, "--target", metavar="KG",
                                     help="Each truck's target load (default: the data's, if it has one)."),
        out: Path = typer.Option(None, "--out", metavar="FILE", help="Also write every pass to this Parquet file."),
    ) -> None:
        """Weigh every bucket pass before its dump, total each truck against its target, record the shift
        (from a dataset, a CAN log or a live bus; on a bus the passes and totals are sent in J1939).

        A truck is done at 30 s without the arm's frames, at the operator's button (a DBC message),
        or on a live bus when the key t is pressed in the terminal (q ends the shift, recorded).

        The decoded signals' units are judged every 5 s (pressures in bar, angles in degrees, rates
        in °/s from a DBC mapped with factor 1): a log is refused in one line naming the signal and
        the factor to set; on a live bus no pass is weighed while it lasts.
        """
        from excavator_payload.data.io import check_output_path
        from excavator_payload.estimators.base import load_estimator
        from excavator_payload.platforms import HYDRAULIC
        from excavator_payload.runtime.loadout import passes_frame

        given = [name for name, v in (("--data", data), ("--log", log), ("--interface", interface)) if v is not None]
        if len(given) != 1:
            raise DatasetError("loadout weighs one of --data FILE, --log FILE or --interface/--channel "
                               + (f"(got {' and '.join(given)})" if given else "(none given)"))
        if (interface is None) != (channel is None):
            raise DatasetError("--interface and --channel go together")
        if data is not None and (dbc_file is not None or signal_map is not None):
            raise DatasetError("--dbc and --signal-map are for a CAN log or bus (--log, --interface)")
        if truth is not None and log is None:
            raise DatasetError("--truth goes with --log (a dataset has its own truth)")
        if interface is None and (bitrate is not None or duration is not None):
            raise DatasetError("--bitrate and --duration are for a live bus (--interface/--channel)")
        if target is not None and not (math.isfinite(target) and target > 0):
            raise DatasetError(f"--target must be a mass above 0 kg, got {target:g}")
        if not (math.isfinite(stale_tolerance) and stale_tolerance >= 1):
            raise DatasetError("--stale-tolerance must be at least 1 (periods)")
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            raise DatasetError("--duration must be a positive number of seconds")
        inputs = [p for p in (data, log, truth, dbc_file, signal_map, db) if p is not None]
        if out is not None:
            if out.suffix.lower() != ".parquet":
                raise DatasetError(f"--out must end in .parquet, got '{out.name}'")
            check_output_path(out, inputs=inputs)
        for source in (data, log, truth, dbc_file, signal_map):
            if source is not None and db.exists() and db.resolve() == Path(source).resolve():
                raise DatasetError(f"--db would overwrite {source}")
        estimator = load_estimator(model)
        if not HYDRAULIC.carries(estimator):
            raise DatasetError(f"loadout weighs the machine sensor set's passes; the model is for the "
                               f"{estimator.sensor_set.name} set")
        rated = getattr(estimator, "rated_payload", None)
        if target is not None and rated and target < TARGET_SHARE * rated:
            # --target 20 meant 20 t: every truck was "full" after its first pass
            raise DatasetError(f"--target {target:g} kg is less than a tenth of one bucket (rated {rated:g} kg): "
                               f"in tonnes? give kg (e.g. --target {target * 1000:g})")
        if target is not None and rated and target > TARGET_MOST * rated:
            # --target 2e7 (grams): every truck "short" by tonnes, every pass still weighed
            raise DatasetError(f"--target {target:g} kg is more than {TARGET_MOST:g} buckets (rated {rated:g} kg), "
                               f"more than a truck takes: in grams? give kg (e.g. --target {target / 1000:g})")
        if data is not None:
            trucks = _from_dataset(estimator, data, db, target, model)
        else:
            trucks = _from_bus(estimator, db, target, model, log, interface, channel, dbc_file, signal_map,
                               stale_tolerance, truth, bitrate, duration)
        n_pass = sum(len(t.passes) for t in trucks)
        n_bad = sum(t.unweighed for t in trucks)
        n_degraded = sum(t.degraded for t in trucks)
        degraded = f", {n_degraded} weighed without a faulty sensor" if n_degraded else ""
        console.print(f"{len(trucks)} trucks, {n_pass} passes ({n_bad} not weighed{degraded}), "
                      f"{sum(t.total for t in trucks):,.0f} kg; recorded in {db}")
        if out is not None:
            frame = passes_frame(trucks)
            tmp = out.with_name(f".{out.name}.tmp")
            frame.to_parquet(tmp, index=False)
            tmp.replace(out)
            console.print(f"passes written to {out}")



def show_truck(truck) -> None:
    """A finished truck: its table, a line with its total against the target, its sensor faults.

    Parameters
    ----------
    truck : Truck
        The finished truck, printed on the console.
    """
    from excavator_payload.runtime.loadout import fault_line, truck_table

    console.print(truck_table(truck))
    line = f"truck {truck.truck}: {len(truck.passes)} passes, total {truck.total:,.0f} kg"
    if truck.target is not None:
        line += f" of {truck.target:,.0f} kg target ({truck.target - truck.total:,.0f} kg left)"
    if truck.unweighed:
        line += f"; {truck.unweighed} pass(es) not weighed"
    if truck.degraded:
        line += f"; {truck.degraded} pass(es) weighed without a faulty sensor (σ widened)"
    console.print(line)
    for fault in truck.faults:
        console.print(f"truck {truck.truck}: " + fault_line(fault), markup=False, highlight=False)


def warn_never_zeroed(estimator) -> None:
    """Say on stderr, once, that ``estimator`` weighs with its calibration session's offsets
    (its ``never_zeroed``; nothing for any other), for a command about to weigh.

    Parameters
    ----------
    estimator : Estimator
        The loaded estimator.
    """
    # Said once the inputs are checked and before the first weight: each truck's first pass is
    # where an unzeroed model's offsets show as an `ok` weight.
    if getattr(estimator, "never_zeroed", False):
        from excavator_payload.estimators.offset_drift import never_zeroed_note

        measured = getattr(estimator, "never_zeroed_measured", None)  # the estimator's own figure
        typer.echo(f"warning: {never_zeroed_note(estimator.name, measured)}", err=True)


def _from_dataset(estimator, data, db, target, model):
    from excavator_payload.data.io import read_dataset
    from excavator_payload.platforms import HYDRAULIC
    from excavator_payload.runtime.loadout import file_key, run_loadout
    from excavator_payload.runtime.shift_record import open_record

    dataset = read_dataset(data)
    if not HYDRAULIC.carries(dataset):
        raise DatasetError(f"loadout weighs the machine sensor set's passes; {data} holds the "
                           f"{dataset.sensor_set.name} set")
    warn_never_zeroed(estimator)
    record = open_record(db, say=_say)
    try:
        return run_loadout(estimator, dataset, record, file_key(data), target, on_truck=show_truck,
                           data_name=str(data), model_name=str(model))
    finally:
        record.close()


def _from_bus(estimator, db, target, model, log, interface, channel, dbc_file, signal_map, stale_tolerance,
              truth, bitrate, duration):
    from excavator_payload.runtime.can_sensor import PayloadSensor
    from excavator_payload.runtime.codec import SignalCodec
    from excavator_payload.runtime.loadout import file_key
    from excavator_payload.runtime.shift_record import open_record
    from excavator_payload.runtime.loadout_bus import BusLoadout, TruckButton, replay_loadout

    from excavator_payload.platforms import HYDRAULIC
    from excavator_payload.runtime.loadout_bus import check_log_units
    from excavator_payload.runtime.loadout_guard import UnitGuard

    codec = SignalCodec.from_files(estimator.sensor_set, dbc_file, signal_map)
    button = TruckButton.from_signal_map(signal_map, codec.database)
    sensor = PayloadSensor(estimator, codec, stale_tolerance=stale_tolerance)

    def guard():
        """The decoded signals' units judged (a DBC in bar, degrees or °/s mapped with factor 1)."""
        return UnitGuard(estimator.sensor_set, codec, getattr(estimator, "machine", None), HYDRAULIC)

    truths = None
    if truth is not None:
        from excavator_payload.data.io import read_dataset

        metas = read_dataset(truth).experiment_meta
        truths = [metas[k].get("passes") or [] for k in sorted(metas)]
        if not any(truths):
            raise DatasetError(f"--truth {truth}: its experiments have no true passes (a --motion shift dataset has)")
    if log is not None:
        from excavator_payload.runtime.logs import read_frames

        next(iter(read_frames(log)), None)  # a missing or unreadable log: one line before the record
        # a signal in another unit: one line before anything is recorded
        check_log_units(log, PayloadSensor(estimator, codec, stale_tolerance=stale_tolerance), guard(),
                        f"CAN log '{log}'")
        warn_never_zeroed(estimator)
        record = open_record(db, say=_say)
        try:
            bus = BusLoadout(sensor, record, file_key(log), target, button, truths=truths, on_truck=show_truck,
                             data_name=str(log), model_name=str(model), guard=guard(), refuse_units=True)
            bus.guard_source = f"CAN log '{log}'"
            trucks = replay_loadout(log, bus, progress=True)
        finally:
            record.close()
        c = sensor.counters
        console.print(f"{c['samples']} samples from {c['frames']} frames ({c['ignored']} of other ids, "
                      f"{c['other_senders']} of the sensor PGNs from other source addresses, "
                      f"{c['other_channels']} of them on a second log channel, {c['bad_frames']} bad); "
                      f"truck changes: {bus.presses} button presses, {bus.gaps} gaps of 30 s or more; "
                      f"units judged on {bus.guard.judged} windows of {bus.guard.size} samples",
                      markup=False, highlight=False)
        if bus.log_end:  # a cut log's trucks looked complete (its last one may be partial)
            typer.echo(f"warning: {bus.log_end}; its last truck may be partial", err=True)
        return trucks
    return _live(sensor, button, db, target, model, interface, channel, bitrate, duration, guard())


def _live(sensor, button, db, target, model, interface, channel, bitrate, duration, guard):
    import datetime
    import queue
    import signal
    import sys
    import threading

    import can
    from rich.live import Live

    from excavator_payload.runtime.dbc import CanConfigError
    from excavator_payload.runtime.loadout_bus import BusLoadout
    from excavator_payload.runtime.loadout_live import COMMAND_HELP, live_view, read_commands, readable_commands, run_live, terminal_keys
    from excavator_payload.runtime.shift_record import KeptRecord, open_record

    kwargs = {"bitrate": bitrate} if bitrate else {}
    try:
        bus = can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, ValueError, ImportError, OSError, NotImplementedError) as exc:
        raise CanConfigError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from None
    warn_never_zeroed(sensor.estimator)
    # a write that fails mid-shift (disk full, read-only, locked, folder gone) keeps the trucks
    # in hand in a file and tries again; the shift goes on (it stopped and lost the truck)
    record = KeptRecord(open_record(db, say=_say))
    # a live session is its own source: a restart appends, never replaces the earlier trucks
    source = f"live {interface}:{channel} {datetime.datetime.now(datetime.timezone.utc).isoformat()}"
    stop = threading.Event()
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, lambda *_: stop.set())
    timer = threading.Timer(duration, stop.set) if duration else None
    done = []
    # the operator's commands (t: next truck, q: end the shift) read on their own thread: a
    # silent keyboard never holds the bus; no stdin (a service, /dev/null) or a background job's
    # terminal is no commands
    commands: queue.Queue = queue.Queue()
    restore = terminal_keys(sys.stdin)
    reader = None
    if readable_commands(sys.stdin):
        def unknown(text):
            console.print(f"unknown command {text!r}: t = next truck, q = end the shift", markup=False,
                          highlight=False)

        reader = threading.Thread(target=read_commands, args=(sys.stdin, commands, unknown, restore is not None),
                                  name="loadout-commands", daemon=True)
        reader.start()
    keys = COMMAND_HELP if restore is not None else COMMAND_HELP.replace("t:", "t + Enter:").replace(
        "q:", "q + Enter:")

    def footer():
        return keys if reader is not None and reader.is_alive() else "Ctrl-C: stop"

    try:
        loadout = BusLoadout(sensor, record, source, target, button, send=True, on_truck=done.append,
                             data_name=f"{interface}:{channel}", model_name=str(model), guard=guard)
        loadout.guard_source = f"bus {interface}:{channel}"
        console.print(f"loadout on {interface}:{channel}; {footer()}")
        if timer:
            timer.start()
        with Live(live_view(loadout, footer()), console=console, refresh_per_second=4, transient=False) as view:
            ticks = [0]

            def refresh():
                ticks[0] += 1
                if ticks[0] % 25 == 0:  # 4 times a second at 100 Hz
                    view.update(live_view(loadout, footer()))

            counters = run_live(bus, loadout, stop, on_tick=refresh, commands=commands,
                                bus_factory=lambda: can.Bus(interface=interface, channel=channel, **kwargs),
                                name=f"{interface}:{channel}")
            view.update(live_view(loadout, footer()))
        if not console.is_terminal:
            console.print()  # the last view has no line end where nothing is redrawn
    finally:
        if restore is not None:
            restore()
        if timer:
            timer.cancel()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        bus.shutdown()
        record.close()
    for truck in done:
        show_truck(truck)
    console.print(f"stopped: {counters['published']} frames sent, {counters['bus_errors']} bus errors; truck "
                  f"changes: {loadout.presses} button presses, {loadout.gaps} gaps of 30 s or more, "
                  f"{counters['truck_commands']} from the terminal; units judged on {guard.judged} windows, "
                  f"{guard.flagged_windows} wrong"
                  + (f"; bus lost {counters['bus_lost']} time(s), {counters['bus_lost_seconds']:g} s"
                     if counters.get("bus_lost") else "")
                  + (f"; bus-off {counters['bus_off']} time(s), {counters['bus_off_seconds']:g} s"
                     if counters.get("bus_off") else ""), markup=False, highlight=False)
    lost = record.lost_line()
    if lost:  # the trucks are shown above and kept in the fallback file: the exit status says it
        raise DatasetError(lost)
    return loadout.trucks
