"""Log formats of a real bus (issue 30): MF4 (as a CANedge writes it), candump -l and candump's
screen format, through ``can-replay`` end to end; a log with nothing of the sensor says what it holds."""

from datetime import datetime
from pathlib import Path

import can
import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.io import read_estimates, write_dataset
from excavator_payload.errors import DatasetError
from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.can_sensor import PayloadSensor
from excavator_payload.runtime.record import record_dataset
from excavator_payload.runtime.replay import replay_log
from excavator_payload.simulation.minimum_jerk import simulate_minimum_jerk


@pytest.fixture(scope="module")
def swings():
    return simulate_minimum_jerk(2, seed=7, noise="thesis")


@pytest.fixture(scope="module")
def model(swings, tmp_path_factory):
    folder = tmp_path_factory.mktemp("model") / "model"
    create_estimator("inverse-dynamics").fit(swings).save(folder)
    return folder


@pytest.fixture(scope="module")
def reference(swings, model, tmp_path_factory):
    """Estimates of the BLF log can-record writes: what every format must give."""
    from excavator_payload.estimators.base import load_estimator

    log = tmp_path_factory.mktemp("ref") / "ref.blf"
    record_dataset(swings, log)
    return replay_log(log, PayloadSensor(load_estimator(model)))


def _frames(swings):
    log_path = None
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "x.blf"
        record_dataset(swings, log_path, start_time=1_700_000_000.0)
        return list(can.LogReader(str(log_path)))


def _replay_cli(tmp_path, model, log, *extra):
    out = tmp_path / "e.parquet"
    code = main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(out), *extra])
    return code, (read_estimates(out) if code == 0 else None)


def _same(got, reference):
    assert list(got["status"]) == list(reference["status"])
    np.testing.assert_allclose(got["payload_estimate"], reference["payload_estimate"], rtol=1e-9)


def test_mf4_written_by_can_record(tmp_path, swings, model, reference):
    data = tmp_path / "d.parquet"
    write_dataset(swings, data)
    log = tmp_path / "swings.MF4"
    assert main(["can-record", "--data", str(data), "--out", str(log)]) == 0
    code, got = _replay_cli(tmp_path, model, log)
    assert code == 0
    _same(got, reference)


def test_mf4_built_like_a_canedge_log(tmp_path, swings, model, reference):
    """An MDF 4 file made with asammdf's own API the way a CANedge logger writes bus logging:
    a CAN_DataFrame channel group (bus-event flag, CAN bus source), times from the file's start."""
    from .field_bus import write_canedge_mf4

    log = write_canedge_mf4(_frames(swings), tmp_path / "00000001.MF4")  # asammdf may lower the suffix
    assert log.is_file()
    code, got = _replay_cli(tmp_path, model, log)
    assert code == 0
    _same(got, reference)


def test_candump_l_log(tmp_path, swings, model, reference):
    lines = [f"({f.timestamp:.6f}) can0 {f.arbitration_id:08X}#{bytes(f.data).hex().upper()}" for f in _frames(swings)]
    for suffix in (".log", ".txt"):
        log = tmp_path / f"candump-2024-01-01_000000{suffix}"
        log.write_text("\n".join(lines) + "\n")
        code, got = _replay_cli(tmp_path, model, log)
        assert code == 0
        _same(got, reference)


def _screen(f, stamp: str | None, extra=""):
    data = "  ".join([""] + [" ".join(f"{b:02X}" for b in f.data)]).strip()
    head = f" ({stamp})" if stamp is not None else ""
    return f"{head}  can0  {extra}{f.arbitration_id:08X}   [{len(f.data)}]  {data}"


@pytest.mark.parametrize("kind", ["absolute", "zero", "delta", "date", "extra-columns"])
def test_candump_screen_format(tmp_path, swings, model, reference, kind):
    frames = _frames(swings)
    t0, lines, previous = frames[0].timestamp, [], frames[0].timestamp
    for f in frames:
        if kind == "absolute" or kind == "extra-columns":
            stamp = f"{f.timestamp:.6f}"
        elif kind == "zero":
            stamp = f"{f.timestamp - t0:010.6f}"
        elif kind == "delta":
            stamp = f"{f.timestamp - previous:010.6f}"
        else:
            stamp = datetime.fromtimestamp(f.timestamp).strftime("%Y-%m-%d %H:%M:%S.%f")
        previous = f.timestamp
        lines.append(_screen(f, stamp, "RX - -  " if kind == "extra-columns" else ""))
    log = tmp_path / "dump.txt"
    log.write_text("\n".join(lines) + "\n")
    code, got = _replay_cli(tmp_path, model, log)
    assert code == 0
    _same(got, reference)


def test_candump_screen_format_without_time_is_one_line(tmp_path, model, swings, capsys):
    log = tmp_path / "dump.log"
    log.write_text("\n".join(_screen(f, None) for f in _frames(swings)[:40]) + "\n")
    capsys.readouterr()
    code, _ = _replay_cli(tmp_path, model, log)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "candump -l" in err and "without timestamps" in err


def test_a_log_of_other_traffic_says_what_it_holds(tmp_path, model):
    """No frame of the sensor: one line with the frames, ids, PGNs, source addresses and rates."""
    log = tmp_path / "truck.asc"
    with can.Logger(str(log)) as w:
        for k in range(200):
            w.on_message_received(can.Message(timestamp=0.01 * k, arbitration_id=0x0CF00400,
                                              is_extended_id=True, data=bytes(8)))  # EEC1 at 100 Hz
            if k % 10 == 0:
                w.on_message_received(can.Message(timestamp=0.01 * k, arbitration_id=0x18FEF100,
                                                  is_extended_id=True, data=bytes(8)))  # CCVS at 10 Hz
    with pytest.raises(DatasetError) as info:
        from excavator_payload.estimators.base import load_estimator

        replay_log(log, PayloadSensor(load_estimator(model)))
    text = str(info.value)
    assert "\n" not in text
    assert "220 frames over 1.99 s from 2 id(s)" in text
    assert "0CF00400 (PGN 0xF004, SA 0x00) 200 at 100 Hz" in text
    assert "18FEF100 (PGN 0xFEF1, SA 0x00) 20 at 10 Hz" in text
    assert "ThesisSensors1: PGN 0xFF00 from SA 0xA0" in text


def test_unknown_text_log_and_compressed_mdf_are_one_line(tmp_path, model, capsys):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello world\n")
    packed = tmp_path / "00000001.MFC"
    packed.write_bytes(b"\x00" * 64)
    for log, said in ((bad, "not a candump log"), (packed, "compressed or encrypted")):
        capsys.readouterr()
        code, _ = _replay_cli(tmp_path, model, log)
        err = capsys.readouterr().err.strip()
        assert code == 2 and said in err and len(err.splitlines()) == 1


def test_samples_decoded_from_a_log_are_the_datasets(tmp_path, swings, model):
    """``can-replay --samples-out`` writes the samples it assembled from the frames as a
    dataset: the recorded dataset's signals within the DBC's resolution, its segments as
    experiments (what a field technician zeroes or plots from a logger's MF4)."""
    from excavator_payload.data.io import read_dataset

    data = tmp_path / "d.parquet"
    write_dataset(swings, data)
    log = tmp_path / "swings.MF4"
    assert main(["can-record", "--data", str(data), "--out", str(log)]) == 0
    samples = tmp_path / "samples.parquet"
    code, _ = _replay_cli(tmp_path, model, log, "--samples-out", str(samples))
    assert code == 0
    got = read_dataset(samples)
    assert got.n_experiments == swings.n_experiments and len(got.frame) == len(swings.frame)
    signals = list(swings.sensor_set.signals)
    np.testing.assert_array_equal(got.frame["experiment"], swings.frame["experiment"])
    np.testing.assert_allclose(got.frame["time"], swings.frame["time"], atol=1e-6)
    want = swings.frame[signals].to_numpy()
    diff = np.abs(got.frame[signals].to_numpy() - want)
    # within the generated DBC's resolution (µrad for angles, about 1 N·m for torques)
    assert np.all(np.nanmax(diff, axis=0) <= 1e-4 * np.abs(want).max(axis=0) + 1e-5)
    assert np.isfinite(got.frame[signals].to_numpy()).mean() > 0.99
    assert main(["can-replay", "--log", str(log), "--model", str(model), "--out", str(tmp_path / "o.parquet"),
                 "--samples-out", str(log)]) == 2  # never over the log


def test_replay_writes_in_chunks_the_same_files(tmp_path, swings, model, reference, monkeypatch):
    """``can-replay`` writes its estimates and decoded samples chunk by chunk (bounded memory on
    a day's log): with chunks of 37 rows the files hold what one in-memory replay gives, the
    rate check keeps a bounded sample of the frame intervals, and a replay that fails leaves
    neither file."""
    from excavator_payload.data.io import read_dataset
    from excavator_payload.runtime import replay

    monkeypatch.setattr(replay, "CHUNK_ROWS", 37)
    monkeypatch.setattr(replay, "RATE_SAMPLE", 50)
    log = tmp_path / "swings.blf"
    record_dataset(swings, log)
    samples = tmp_path / "samples.parquet"
    code, got = _replay_cli(tmp_path, model, log, "--samples-out", str(samples))
    assert code == 0 and len(got) == len(reference) > 37 * 3
    for column in ("experiment", "status", "stale_signals", "fault"):
        assert got[column].tolist() == reference[column].tolist()
    np.testing.assert_array_equal(got["payload_estimate"], reference["payload_estimate"])
    decoded = read_dataset(samples)
    assert len(decoded.frame) == len(swings.frame) and decoded.n_experiments == swings.n_experiments
    np.testing.assert_allclose(decoded.frame["time"], swings.frame["time"], atol=1e-6)
    # a log with no sensor frame: neither file is written, no temporary file is left
    other = tmp_path / "other"
    other.mkdir()
    empty = other / "empty.asc"
    empty.write_text("date Mon Jan 1 00:00:00.000 am 2024\nbase hex timestamps absolute\n"
                     "   0.000000 1  123             Rx   d 1 00\n   0.010000 1  123             Rx   d 1 00\n")
    code = main(["can-replay", "--log", str(empty), "--model", str(model), "--out", str(other / "e.parquet"),
                 "--samples-out", str(other / "s.parquet")])
    assert code == 2 and sorted(p.name for p in other.iterdir()) == ["empty.asc"]


def test_rate_check_keeps_a_uniform_sample_of_intervals():
    """The rate check's intervals are a bounded, uniform sample of them all (reservoir)."""
    import random
    from collections import Counter

    from excavator_payload.runtime.replay import RATE_SAMPLE, _keep_interval

    kept, seen, pick = [], Counter(), random.Random(0)
    for i in range(20 * RATE_SAMPLE):
        _keep_interval(kept, seen, "m", float(i), pick)
    assert len(kept) == RATE_SAMPLE and seen["m"] == 20 * RATE_SAMPLE
    # uniform over the whole log: its median near the middle, not the first RATE_SAMPLE's
    assert abs(np.median(kept) / (10 * RATE_SAMPLE) - 1) < 0.05


def test_decoded_samples_whose_time_goes_back_leave_no_file(tmp_path, swings):
    """A segment whose decoded time goes back stops the ``--samples-out`` file with one line
    (the estimates are not its concern); none is left half-written."""
    from excavator_payload.data.io import ParquetStreamWriter
    from excavator_payload.runtime.replay import ReplaySamples, samples_file_meta

    target = tmp_path / "s.parquet"
    n = len(swings.sensor_set.signals)
    kept = ReplaySamples(swings.sensor_set, "x.blf", ParquetStreamWriter(target, samples_file_meta(
        swings.sensor_set, "x.blf")))
    for t in (0.0, 0.01, 0.02, 0.015):
        kept.append((0, t, np.zeros(n)))
    with pytest.raises(DatasetError, match="does not increase within segment 0"):
        kept.close()
    assert list(tmp_path.iterdir()) == []
