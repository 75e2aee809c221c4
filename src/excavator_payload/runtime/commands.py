"""``excavator-payload can-run``, ``can-replay``, ``can-record`` and ``export``."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path

import typer
from rich.console import Console

from excavator_payload.errors import DatasetError, EstimatorError
from excavator_payload.runtime.exportable import format_help

console = Console()
err_console = Console(stderr=True)

DBC_HELP = ("The sensors' DBC file (default: the sensor set's generated J1939 DBC, see "
            "`excavator-payload can-dbc`). Needs --signal-map.")
MAP_HELP = ("TOML map from our signal names to (message, signal, factor, offset) in --dbc; "
            "factor and offset convert the DBC's unit to SI.")


def _codec(estimator, dbc_file, signal_map):
    from excavator_payload.runtime.codec import SignalCodec

    return SignalCodec.from_files(estimator.sensor_set, dbc_file, signal_map)


def register(app: typer.Typer) -> None:
    """Add ``can-dbc``, ``can-record``, ``can-replay``, ``can-run`` and ``export`` to ``app``.

    Parameters
    ----------
    app : typer.Typer
        The command-line application the commands are added to.
    """

    from excavator_payload.runtime import loadout_command

    loadout_command.register(app)

    @app.command("can-dbc")
    def can_dbc(
        sensor_set: str = typer.Option("thesis", "--sensor-set", help="Sensor set: thesis or machine."),
        out: Path = typer.Option(None, "--out", help="Write the DBC here (default: print it)."),
    ) -> None:
        """Print or write the J1939 DBC generated from a sensor set."""
        from excavator_payload.data.io import check_output_path
        from excavator_payload.data.schema import get_sensor_set
        from excavator_payload.runtime.dbc import generate_dbc

        text = generate_dbc(get_sensor_set(sensor_set))
        if out is None:
            typer.echo(text, nl=False)
            return
        check_output_path(out)  # a folder or an unwritable place: one line, not a traceback
        if out.suffix.lower() != ".dbc":  # `--out data.parquet` replaced a dataset with DBC text
            raise DatasetError(f"--out must end in .dbc, got '{out.name}'")
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(out)
        console.print(f"wrote [bold]{out}[/bold]")

    @app.command("can-record")
    def can_record(
        data: Path = typer.Option(..., "--data", help="Dataset (Parquet) to turn into frames."),
        out: Path = typer.Option(..., "--out", help="CAN log to write: .asc, .blf, .log (candump -l), "
                                 ".csv, .trc or .mf4 (MDF 4 bus logging, as a CANedge writes)."),
        dbc_file: Path = typer.Option(None, "--dbc", help=DBC_HELP),
        signal_map: Path = typer.Option(None, "--signal-map", help=MAP_HELP),
        jitter: float = typer.Option(0.0, "--jitter", help="Standard deviation (s) of each frame's "
                                     "timestamp jitter (clipped at 3 sigma and a third of the period)."),
        burst_every: float = typer.Option(0.0, "--burst-every", help="Every this many seconds, hold one "
                                          "message back and send 3 of its frames back to back (0: never)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the jitter and the bursts."),
    ) -> None:
        """Turn a dataset into a CAN log (every sample as its sensor frames, experiments apart; each
        message at its DBC period, GenMsgCycleTime, where it has one)."""
        from excavator_payload.data.io import read_dataset
        from excavator_payload.runtime.codec import SignalCodec
        from excavator_payload.runtime.record import record_dataset

        from excavator_payload.data.io import check_output_path

        # all the inputs, not only --data: --out DBC or map would have been overwritten
        check_output_path(out, inputs=[data, dbc_file, signal_map])
        dataset = read_dataset(data)
        codec = SignalCodec.from_files(dataset.sensor_set, dbc_file, signal_map)
        info = record_dataset(dataset, out, codec, progress=True, jitter=jitter, burst_every=burst_every,
                              seed=seed)
        console.print(f"{info['frames']} frames of {info['samples']} samples "
                      f"({info['experiments']} experiments, {info['duration']:.1f} s of bus time) "
                      f"written to [bold]{out}[/bold]")

    @app.command("can-replay")
    def can_replay(
        log: Path = typer.Option(..., "--log", help="Recorded CAN log: .asc, .blf, .log (candump -l or "
                                 "candump's screen format with timestamps), .txt, .csv, .trc or .mf4."),
        model: Path = typer.Option(..., "--model", help="Folder of a saved estimator."),
        out: Path = typer.Option(..., "--out", help="Estimates file to write (Parquet)."),
        dbc_file: Path = typer.Option(None, "--dbc", help=DBC_HELP),
        signal_map: Path = typer.Option(None, "--signal-map", help=MAP_HELP),
        segment_gap: float = typer.Option(2.0, "--segment-gap",
                                          help="A silence of the sensor's own frames longer than this (s) "
                                          "starts a new experiment."),
        stale_tolerance: float = typer.Option(3.5, "--stale-tolerance", help="A signal older than its "
                                              "message's period times this makes the sample 'stale'."),
        samples_out: Path = typer.Option(None, "--samples-out", help="Also write the samples decoded "
                                         "from the log as a dataset (Parquet, SI units; NaN where "
                                         "stale): e.g. an empty-bucket motion for `zero --data`."),
    ) -> None:
        """Replay a CAN log through the payload sensor; write the estimates as Parquet (both files
        written as the log is read: a day's log replays in bounded memory)."""
        from contextlib import ExitStack

        from rich.markup import escape

        from excavator_payload.data.io import PARQUET_SUFFIXES, ParquetStreamWriter, check_output_path
        from excavator_payload.estimators.base import load_estimator
        from excavator_payload.estimators.commands import STATUS_MEANING, counts_breakdown
        from excavator_payload.runtime.can_sensor import PayloadSensor
        from excavator_payload.runtime.replay import (ReplayEstimates, ReplaySamples, replay_log,
                                                      samples_file_meta)

        # --out inside the model folder replaced its arrays.npz (the model was lost); the log,
        # the DBC and the map are inputs too
        check_output_path(out, inputs=[log, model, dbc_file, signal_map], suffixes=PARQUET_SUFFIXES)
        if samples_out is not None:
            check_output_path(samples_out, inputs=[log, model, dbc_file, signal_map, out], option="--samples-out",
                              suffixes=PARQUET_SUFFIXES)
        if not segment_gap > 0:
            raise DatasetError("--segment-gap must be positive")
        est = load_estimator(model)
        if not stale_tolerance >= 1:
            raise DatasetError("--stale-tolerance must be at least 1 (periods)")
        sensor = PayloadSensor(est, _codec(est, dbc_file, signal_map), stale_tolerance=stale_tolerance)
        samples_error = ""
        with ExitStack() as files:  # a replay that fails leaves neither file (nor half of one)
            writer = files.enter_context(ParquetStreamWriter(
                out, {"estimator": est.name, "model": str(model), "log": str(log)}))
            samples = None
            if samples_out is not None:
                samples = ReplaySamples(est.sensor_set, log, files.enter_context(
                    ParquetStreamWriter(samples_out, samples_file_meta(est.sensor_set, log))))
            estimates = replay_log(log, sensor, segment_gap, progress=True, samples=samples,
                                   estimates=ReplayEstimates(writer))
            writer.close()
            if samples is not None:
                try:  # the estimates stay written whatever becomes of the samples
                    n = samples.close()
                    console.print(f"{n} decoded samples in {samples.segments} segment(s) written to "
                                  f"{samples_out}", markup=False, highlight=False)
                except DatasetError as exc:
                    samples_error = str(exc)
        c = sensor.counters
        attrs = estimates.attrs
        dropped = [f"{n} {what}" for n, what in (
            (attrs.get("skipped_records", 0), "unreadable log records skipped"),
            (c["duplicates"], "duplicate frames dropped"),
            (c["other_senders"], "frames of the sensor PGNs from another source address ignored"),
            (c["other_channels"], "frames of the sensor messages on a second log channel (a bridged copy) ignored"))
            if n]
        # every status, as `estimate` counts them (it said '(9244 ok)', no word of the warming_up)
        console.print(f"{est.name}: {estimates.count} estimates ({counts_breakdown(estimates.statuses)}) in "
                      f"{estimates.segments} segment(s) from {c['frames']} frames ({c['ignored']} "
                      f"ignored, {c['bad_frames']} bad{''.join('; ' + d for d in dropped)}) written to "
                      f"[bold]{escape(str(out))}[/bold]", highlight=False)
        seen = [status for status in STATUS_MEANING if estimates.statuses[status]]
        if seen:
            console.print("; ".join(f"{status}: {STATUS_MEANING[status]}" for status in seen),
                          markup=False, highlight=False)
        if estimates.stale:
            console.print("stale signals: " + ", ".join(f"{n} ({k} samples)" for n, k in
                                                        estimates.stale.most_common()),
                          markup=False, highlight=False)
        for line in sensor.dm1.summary():  # what the bus would have carried (J1939 DM1)
            console.print(line, markup=False, highlight=False)
        if attrs.get("log_end"):  # a cut log's estimates looked complete
            typer.echo(f"warning: {attrs['log_end']}", err=True)
        loadout_command.warn_never_zeroed(est)
        if samples_error:
            raise DatasetError(samples_error)

    @app.command("can-run")
    def can_run(
        interface: str = typer.Option(..., "--interface", help="python-can interface: socketcan, "
                                      "pcan, kvaser, vector, virtual, …"),
        channel: str = typer.Option(..., "--channel", help="Channel of the interface, e.g. can0."),
        model: Path = typer.Option(..., "--model", help="Folder of a saved estimator."),
        bitrate: int = typer.Option(None, "--bitrate", help="Bit rate, if the interface needs one "
                                    "(J1939: 250000 or 500000)."),
        dbc_file: Path = typer.Option(None, "--dbc", help=DBC_HELP),
        signal_map: Path = typer.Option(None, "--signal-map", help=MAP_HELP),
        stale_after: float = typer.Option(None, "--stale-after", help="Status 'stale' after this many "
                                          "seconds without a sample (default: 3 sample periods)."),
        duration: float = typer.Option(None, "--duration", help="Stop after this many seconds "
                                       "(default: run until SIGINT/SIGTERM)."),
    ) -> None:
        """Run the payload sensor on a CAN bus: read sensor frames, publish PayloadEstimate and
        VehicleWeight at the sensor rate, until stopped (Ctrl-C / SIGTERM). A lost bus (the
        interface gone) is reopened every 1-5 s and bus-off waited out; each is said once."""
        import can

        from excavator_payload.estimators.base import load_estimator
        from excavator_payload.runtime.can_sensor import PayloadSensor, run_bus
        from excavator_payload.runtime.dbc import CanConfigError

        logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(message)s")
        est = load_estimator(model)
        sensor = PayloadSensor(est, _codec(est, dbc_file, signal_map), stale_after)
        # the first sample's gate imports scipy.stats (5 s on a loaded machine): before the bus
        # is open, not while the first frames queue up
        import scipy.stats  # noqa: F401

        kwargs = {"bitrate": bitrate} if bitrate else {}

        def open_bus():  # also reopens a lost bus (an unplugged adapter, a vanished interface)
            return can.Bus(interface=interface, channel=channel, **kwargs)

        try:
            bus = open_bus()
        except (can.CanError, ValueError, ImportError, OSError, NotImplementedError) as exc:
            raise CanConfigError(f"cannot open CAN interface {interface!r} channel {channel!r}: "
                                 f"{exc}") from None
        loadout_command.warn_never_zeroed(est)  # before the first estimate goes on the bus
        stop = threading.Event()
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, lambda *_: stop.set())
        timer = threading.Timer(duration, stop.set) if duration else None
        if timer:
            timer.start()
        console.print(f"{est.name} on {interface}:{channel} ({est.sensor_set.name} sensors, "
                      f"{est.sensor_set.sample_rate:g} Hz); Ctrl-C stops")
        try:
            counters = run_bus(bus, sensor, stop, bus_factory=open_bus, name=f"{interface}:{channel}")
        finally:
            if timer:
                timer.cancel()
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
            bus.shutdown()
        # counters are printed as they are (bus_lost_seconds: s, to 0.1 s)
        console.print("stopped: " + ", ".join(f"{k} {v}" for k, v in counters.items()), markup=False,
                      highlight=False)

    @app.command("export")
    def export(
        model: Path = typer.Option(..., "--model", help="Folder of a saved estimator."),
        fmt: str = typer.Option(..., "--format", help=format_help()),
        out: Path = typer.Option(..., "--out", help="Folder to write the files into."),
        precision: str = typer.Option("float64", "--precision", help="C only: float64 (double) or "
                                      "float32 (single-precision FPUs)."),
    ) -> None:
        """Export a trained estimator as C99 source for an ECU, or as ONNX."""
        from excavator_payload.estimators.base import load_estimator

        from excavator_payload.data.io import check_output_path

        if precision not in ("float64", "float32"):
            raise EstimatorError("--precision must be float64 or float32")
        # a file, a path under a file or the model folder: one line before any work (it was
        # "File exists ('x')", or the C files written into the model)
        check_output_path(out, inputs=[model], kind="folder")
        est = load_estimator(model)
        if fmt == "c":
            from excavator_payload.runtime.export_c import export_c

            files = export_c(est, out, precision=precision)
        elif fmt == "onnx":
            if precision != "float64":
                raise EstimatorError("--precision applies to --format c only")
            from excavator_payload.runtime.export_onnx import export_onnx

            files = export_onnx(est, out)
        else:
            raise EstimatorError(f"--format must be c or onnx, got {fmt!r}")
        for f in files:
            console.print(f"wrote [bold]{f}[/bold]")
