"""The sensor health monitor in the C export (runtime/export_c/health.py) equals Python's
(estimators/health.py, run by ``Estimator.step_values``) sample by sample: status codes, the
signals and kinds named (``ep_faults`` against ``StepResult.fault``), estimates and ``ep_sigma``,
with ``Estimator.health = True``, on clean work and on work with a fault of every kind the
monitor knows injected (stuck, dropout, disagree, noise, offset, gain), for two estimators of the
machine sensor set; ``-DEP_HEALTH=0`` is ``health = False``; the thesis set's export has no
monitor."""

import copy
import subprocess

import numpy as np
import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators import health
from excavator_payload.estimators.base import Status, create_estimator
from excavator_payload.runtime.c_harness import STRICT_FLAGS, _rows, build, c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.runtime.export_c.c_text import c_number
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")

CODES = {s.value: i for i, s in enumerate(Status)}
SIGNALS = list(MACHINE_SENSORS.signals)
DEG, BAR = np.pi / 180.0, 1e5
C_KINDS = (*health.KINDS, "balance")  # ep_faults' kinds: the monitor's, then the kernel's joint check

# prints estimate, status, sigma and the fault mask of every kind, per sample
HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include "HEADER"

int main(void)
{
    char line[8192];
    ep_state s;
    while (fgets(line, sizeof line, stdin)) {
        char *p = line, *end;
        ep_real v[EP_N_SIGNALS], est, t;
        int j, k, status, start = (int)strtol(p, &end, 10);
        p = end;
        t = (ep_real)strtod(p, &end);
        p = end;
        for (j = 0; j < EP_N_SIGNALS; ++j) {
            v[j] = (ep_real)strtod(p, &end);
            p = end;
        }
        if (start) ep_reset(&s);
        status = ep_step(&s, t, v, &est);
        printf("%.17g %d %.17g", (double)est, status, (double)ep_sigma(&s));
        for (k = 0; k < EP_N_FAULT_KINDS; ++k) printf(" %lu", ep_faults(&s, k));
        printf("\n");
    }
    return 0;
}
"""


def _run_c(c_file, dataset, folder, single=False, extra_flags=()):
    """Estimate, status, sigma and the fault set per sample from the compiled export."""
    obj = build(c_file, folder, single=single, extra_flags=extra_flags).object_file
    harness = folder / "faults.c"
    harness.write_text(HARNESS.replace("HEADER", str(c_file.with_suffix(".h").resolve())))
    binary = folder / "faults"
    defines = ["-DEP_SINGLE=1" if single else "-DEP_SINGLE=0", *extra_flags]
    subprocess.run([c_compiler(), *STRICT_FLAGS, "-O2", *defines, str(harness), str(obj), "-o", str(binary),
                    "-lm"], check=True, capture_output=True, text=True)
    out = subprocess.run([str(binary)], input=_rows(dataset), check=True, capture_output=True, text=True,
                         timeout=120).stdout.splitlines()
    rows = [line.split() for line in out]
    est = np.array([float(r[0]) for r in rows])
    status = np.array([int(r[1]) for r in rows])
    sigma = np.array([float(r[2]) for r in rows])
    faults = [frozenset(f"{SIGNALS[i]}:{kind}" for k, kind in enumerate(C_KINDS)
                        for i in range(len(SIGNALS)) if int(r[3 + k]) >> i & 1) for r in rows]
    return est, status, sigma, faults


def _assert_equal(est, c_file, dataset, folder, single=False, extra_flags=()):
    """C == Python sample by sample: statuses, fault sets, estimates and sigma (the tolerances of
    tests/runtime/test_export_c.py)."""
    py = est.estimate(dataset)
    got, status, sigma, faults = _run_c(c_file, dataset, folder, single, extra_flags)
    want_status = np.array([CODES[s] for s in py["status"]])
    bad = np.flatnonzero(status != want_status)
    assert bad.size == 0, (f"{bad.size} statuses differ, first at row {bad[0]}: C {status[bad[0]]}, "
                           f"Python {py['status'].iloc[bad[0]]} ({py['fault'].iloc[bad[0]]})")
    want_faults = [frozenset(filter(None, f.split(","))) for f in py["fault"]]
    diff = [i for i, (a, b) in enumerate(zip(faults, want_faults)) if a != b]
    assert not diff, f"fault sets differ at {len(diff)} rows, first {diff[0]}: C {faults[diff[0]]}, " \
                     f"Python {want_faults[diff[0]]}"
    want, want_sigma = py["payload_estimate"].to_numpy(), py["sigma"].to_numpy()
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(np.isnan(sigma), np.isnan(want_sigma))
    ok, ok_sigma = ~np.isnan(want), ~np.isnan(want_sigma)
    if single:
        assert np.abs(got[ok] - want[ok]).max(initial=0.0) <= 0.1
        # a degraded sigma adds the estimate's move since the degraded samples began, and with it
        # the float estimate's rounding (a few 1e-4 kg)
        np.testing.assert_allclose(sigma[ok_sigma], want_sigma[ok_sigma], rtol=1e-4, atol=2e-3)
    else:
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(sigma[ok_sigma], want_sigma[ok_sigma], rtol=1e-6)
    return py


@pytest.fixture(scope="module")
def models():
    fitting = simulate_machine_dataset(3, seed=3)
    out = {"inverse-dynamics": create_estimator("inverse-dynamics", machine="cat345c-hydraulic").fit(fitting),
           "calibrated-momentum": create_estimator("calibrated", machine="cat345c-hydraulic-3pct",
                                                   balance="momentum").fit(fitting)}
    for est in out.values():
        assert est.health and est.health_reference  # fitted on noisy data: the monitor and its noise check
    return out


@pytest.fixture(scope="module")
def clean():
    """Clean operator motion (another seed and session than the fitting data)."""
    return simulate_machine_dataset(2, seed=31, session=2, motion="operator")


def _inject(frame, rows, signal, kind, a, b, size, rng):
    """Fault ``kind`` of ``size`` on ``signal``, rows a:b of one experiment's ``rows``."""
    idx = rows[a:b]
    if kind == "stuck":
        frame.loc[idx, signal] = frame.loc[rows[a - 1], signal]
    elif kind == "dropout":
        frame.loc[idx, signal] = 0.0
    elif kind == "noise":
        frame.loc[idx, signal] += size * rng.standard_normal(len(idx))
    elif kind == "offset":
        frame.loc[idx, signal] += size
    elif kind == "gain":
        frame.loc[idx, signal] *= size


def _with_faults(clean, seed, cases):
    """The clean work with ``cases`` — (experiment 0 or 1, signal, kind, first row, end row,
    size) — injected by :func:`_inject`, drawing from ``seed``: the frame (a copy) and the two
    experiments' row indices."""
    frame = clean.frame.copy()
    rng = np.random.default_rng(seed)
    rows = [frame.index[frame["experiment"] == e] for e in clean.experiment_ids]
    for which, signal, kind, a, b, size in cases:
        _inject(frame, rows[which], signal, kind, a, b, size, rng)
    return frame, rows


@pytest.fixture(scope="module")
def faulty(clean):
    """The clean work with faults of every kind (as benchmarks/bench_faults.py injects them) and a
    hole in time (the monitor's windows restart)."""
    frame, (_, r1) = _with_faults(clean, 5, [
        (0, "boom_head_pressure", "stuck", 300, 420, None),
        (0, "dipper_rod_pressure", "dropout", 600, 650, None),
        (0, "boom_angle", "offset", 900, 1300, 5 * DEG),         # disagree at its edges, then offset
        (0, "bucket_head_pressure", "noise", 1400, 1600, 10 * BAR),
        (1, "dipper_angle", "gain", 400, 1600, 1.25),
        (1, "house_pitch", "offset", 2000, 2400, 5 * DEG),
        (1, "slew_rate", "stuck", 2600, 2800, None),
        (1, "boom_rate", "noise", 3000, 3200, 1.5 * DEG),
    ])
    frame = frame.drop(index=list(r1[1800:1830])).reset_index(drop=True)  # 0.3 s hole
    return Dataset(frame, clean.meta)


def test_c_monitor_equals_python_on_clean_work(models, clean, tmp_path):
    est = models["calibrated-momentum"]
    source = export_c(est, tmp_path / "export")[1]
    py = _assert_equal(est, source, clean, tmp_path / "build")
    assert "ok" in set(py["status"])


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated-momentum"])
def test_c_monitor_equals_python_on_faults_of_every_kind(name, models, faulty, tmp_path):
    source = export_c(models[name], tmp_path / "export")[1]
    py = _assert_equal(models[name], source, faulty, tmp_path / "build")
    kinds = {item.partition(":")[2] for f in py["fault"] for item in filter(None, f.split(","))}
    assert kinds == set(health.KINDS)  # every kind of the monitor was named, in C alike
    assert (py["status"] == "sensor_fault").sum() > 100


def test_c_names_a_lasting_rate_bias_by_the_tracks_slope_as_python_does(models, clean, tmp_path):
    """A bucket rate 1 °/s high from 5 s to the end: only the track's slope bound names it
    (offset); C names the same samples as Python."""
    frame = clean.frame.copy()
    rows = frame.index[frame["experiment"] == clean.experiment_ids[0]]
    frame.loc[rows[500:], "bucket_rate"] += 1.0 * DEG
    est = models["calibrated-momentum"]
    source = export_c(est, tmp_path / "export")[1]
    py = _assert_equal(est, source, Dataset(frame, clean.meta), tmp_path / "build")
    assert py["fault"].str.contains("bucket_rate:offset").any()


def test_c_names_a_tilt_ramp_by_the_tilts_own_limit_as_python_does(models, clean, tmp_path):
    """The house roll ramping at 2 °/s for 3 s: named offset (house pitch and roll) by the tilt's
    own limit (TILT_OFFSET_LIMIT), within 0.9 s; C names the same samples as Python."""
    frame = clean.frame.copy()
    rows = frame.index[frame["experiment"] == clean.experiment_ids[0]]
    t = frame.loc[rows, "time"].to_numpy(float)
    a = 800
    frame.loc[rows[a:a + 300], "house_roll"] += 2.0 * DEG * (t[a:a + 300] - t[a])
    est = models["calibrated-momentum"]
    source = export_c(est, tmp_path / "export")[1]
    assert f"#define EP_HM_TILT_OFFSET_LIMIT {c_number(health.TILT_OFFSET_LIMIT)}" in source.read_text()
    py = _assert_equal(est, source, Dataset(frame, clean.meta), tmp_path / "build")
    named = np.flatnonzero(py["fault"].str.contains("house_roll:offset").to_numpy())
    assert named.size and a <= named[0] - rows[0] <= a + 90


def test_float_build_names_the_same_faults(models, faulty, tmp_path):
    """Single precision (the C rounds the inputs to float, Python does not): on these data the
    same statuses and faults, the estimates within 0.1 kg."""
    est = models["calibrated-momentum"]
    source = export_c(est, tmp_path / "export", precision="float32")[1]
    _assert_equal(est, source, faulty, tmp_path / "build", single=True)


def test_monitor_compiled_out_is_health_off(models, faulty, tmp_path):
    """-DEP_HEALTH=0 is ``Estimator.health = False``: no sensor_fault, every mask 0 (the default
    build names the faults: the test above)."""
    est = copy.deepcopy(models["calibrated-momentum"])
    source = export_c(est, tmp_path / "export")[1]
    est.health = False
    py = _assert_equal(est, source, faulty, tmp_path / "off", extra_flags=("-DEP_HEALTH=0",))
    assert "sensor_fault" not in set(py["status"])
    # an estimator with health off exports the monitor off by default (-DEP_HEALTH=1 turns it on)
    assert "#define EP_HEALTH 0" in export_c(est, tmp_path / "off-export")[0].read_text()


def test_constants_are_read_at_export_time(models, faulty, tmp_path, monkeypatch):
    """The thresholds come from estimators/health.py when exporting: a retuned limit and hold
    are exported as they are, and C still equals Python (which reads the same module)."""
    est = copy.deepcopy(models["calibrated-momentum"])
    before = export_c(est, tmp_path / "before")[1].read_text()
    monkeypatch.setattr(health, "OFFSET_LIMIT", 0.02)
    monkeypatch.setattr(health, "LINK_OFFSET_LIMIT", {"boom": 0.012})
    monkeypatch.setattr(health, "HOLD", 0.35)
    monkeypatch.setattr(health, "STUCK_QUANTA", 4.0)
    monkeypatch.setattr(health, "TILT_OFFSET_LIMIT", 0.03)
    est._health_for = None  # a fresh monitor with the new constants
    source = export_c(est, tmp_path / "export")[1]
    text = source.read_text()
    assert text != before and "#define EP_HM_HOLD 35" in text
    # per link (boom, dipper, bucket): the boom's own limit, the others the general one
    assert "EP_HM_OFFSET_LIMIT[3] = {\n    EP_C(0.012), EP_C(0.02), EP_C(0.02)\n};" in text
    assert "#define EP_HM_TILT_OFFSET_LIMIT EP_C(0.03)" in text
    _assert_equal(est, source, faulty, tmp_path / "build")


def test_model_without_noise_reference(models, faulty, tmp_path):
    """A model saved before the noise check (no ``health_reference``): no noise kind, in C alike."""
    est = copy.deepcopy(models["calibrated-momentum"])
    est.health_reference = None
    est._health_for = None
    source = export_c(est, tmp_path / "export")[1]
    assert "#define EP_HM_NOISE_CHECKED 0" in source.read_text()
    py = _assert_equal(est, source, faulty, tmp_path / "build")
    assert not any("noise" in f for f in py["fault"])


def test_thesis_export_has_no_monitor(tmp_path):
    """The monitor runs on the machine set only (health.for_sensor_set): the thesis set's C has
    none of it."""
    from excavator_payload.simulation.generate import simulate_dataset

    swings = simulate_dataset(2, seed=8, workers=1, noise="thesis", progress=False)
    header, source = export_c(create_estimator("inverse-dynamics").fit(swings), tmp_path)
    assert "EP_HEALTH" not in header.read_text() + source.read_text()
    assert "ep_faults" not in header.read_text()


def test_float_monitor_does_no_double_maths(models, tmp_path):
    """In single precision the monitor promotes nothing to double (an ECU with a float FPU)."""
    header, source = export_c(models["calibrated-momentum"], tmp_path, precision="float32")
    assert "#define EP_HEALTH 1" in header.read_text()
    result = subprocess.run([c_compiler(), *STRICT_FLAGS, "-Wdouble-promotion", "-O0", "-c", str(source),
                             "-o", str(tmp_path / "model.o")], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


@pytest.fixture(scope="module")
def rate_faults(clean):
    """The clean work with a link rate stuck, dropped out and noisy (the monitor names only the
    rate: degraded weighing on the angle's slope), and the slew rate stuck (no substitute)."""
    frame, _ = _with_faults(clean, 7, [
        (0, "boom_rate", "stuck", 500, 700, None),
        (0, "dipper_rate", "dropout", 1200, 1400, None),
        (1, "bucket_rate", "noise", 600, 900, 1.5 * DEG),
        (1, "slew_rate", "stuck", 1500, 1700, None),
    ])
    return Dataset(frame, clean.meta)


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated-momentum"])
@pytest.mark.parametrize("single", [False, True])
def test_c_weighs_degraded_as_python_does(name, single, models, rate_faults, tmp_path):
    """Degraded weighing in C: the same statuses (degraded, code 13), the rate still named in
    ep_faults, the estimates and the widened sigma equal to Python's."""
    est = models[name]
    source = export_c(est, tmp_path / "export", precision="float32" if single else "float64")[1]
    py = _assert_equal(est, source, rate_faults, tmp_path / "build", single=single)
    degraded = py["status"] == Status.DEGRADED.value
    if set(est.DEGRADED_RATES):
        assert degraded.sum() > 50
        assert (py["fault"][degraded] != "").all()
    assert "#define EP_STATUS_DEGRADED 13" in source.with_suffix(".h").read_text()


@pytest.fixture(scope="module")
def pressure_faults(clean):
    """The clean work with a boom head pressure stuck, a dipper rod pressure dropped out and a
    bucket head pressure noisy: ``calibrated`` (momentum) weighs on without their joints."""
    frame, _ = _with_faults(clean, 9, [
        (0, "boom_head_pressure", "stuck", 500, 800, None),
        (0, "dipper_rod_pressure", "dropout", 1200, 1400, None),
        (1, "bucket_head_pressure", "noise", 600, 900, 10 * BAR),
        (1, "boom_rod_pressure", "dropout", 1500, 1600, None),
    ])
    return Dataset(frame, clean.meta)


@pytest.mark.parametrize("single", [False, True])
def test_c_weighs_without_a_named_pressures_joint_as_python_does(single, models, pressure_faults, tmp_path):
    """A named cylinder pressure in C: the same degraded statuses, the pressure named in
    ep_faults, the estimates and sigma equal to Python's (its joint dropped: ring_drop); the
    models that do not weigh without a joint export none of it (their C as before)."""
    est = models["calibrated-momentum"]
    header, source = export_c(est, tmp_path / "export", precision="float32" if single else "float64")
    assert "EP_HM_DROPPED" in header.read_text() and "ring_drop" in source.read_text()
    py = _assert_equal(est, source, pressure_faults, tmp_path / "build", single=single)
    degraded = (py["status"] == Status.DEGRADED.value).to_numpy()
    assert degraded.sum() > 100
    named = {item.partition(":")[0] for f in py["fault"][degraded] for item in f.split(",")}
    assert named <= {"boom_head_pressure", "dipper_rod_pressure", "bucket_head_pressure", "boom_rod_pressure"}
    assert len(named) >= 2
    text = export_c(models["inverse-dynamics"], tmp_path / "id")[1].read_text()
    assert "ring_drop" not in text and "EP_HM_DROP_JOINT" not in text


@pytest.fixture(scope="module")
def angle_faults(clean):
    """The clean work with a boom angle stuck for 8 s (past the substitute's bound) and a bucket
    angle stuck for 3 s: ``calibrated`` (momentum) integrates the rate from the last healthy angle."""
    frame, _ = _with_faults(clean, 11, [
        (0, "boom_angle", "stuck", 500, 1300, None),
        (1, "bucket_angle", "stuck", 600, 900, None),
        (1, "dipper_angle", "stuck", 1500, 1800, None),
    ])
    return Dataset(frame, clean.meta)


@pytest.mark.parametrize("single", [False, True])
def test_c_integrates_a_lost_angle_as_python_does(single, models, angle_faults, tmp_path):
    """A stuck link angle in C: the same degraded statuses while its reference plus the integrated
    rate stands in (health.ANGLE_SUBSTITUTE_LIMIT), then sensor_fault, the estimates and sigma
    equal to Python's."""
    est = models["calibrated-momentum"]
    header, source = export_c(est, tmp_path / "export", precision="float32" if single else "float64")
    assert "ep_hm_angle_refs" in source.read_text()
    py = _assert_equal(est, source, angle_faults, tmp_path / "build", single=single)
    degraded = (py["status"] == Status.DEGRADED.value).to_numpy()
    assert degraded.sum() > 50
    assert all("_angle:" in f for f in py["fault"][degraded])
    text = export_c(models["inverse-dynamics"], tmp_path / "id")[1].read_text()
    assert "ep_hm_angle_refs" not in text and "EP_HM_INT_LINK" not in text


@pytest.fixture(scope="module")
def tilt_faults(clean):
    """The clean work with a house pitch 5° off for 3 s, a house roll stuck for 8 s (past the
    substitute's bound) and a noisy pitch: ``calibrated`` (momentum) weighs on with the tilt from
    before the fault."""
    frame, _ = _with_faults(clean, 13, [
        (0, "house_pitch", "offset", 500, 800, 5 * DEG),
        (1, "house_roll", "stuck", 600, 1400, None),
        (1, "house_pitch", "noise", 1800, 2000, 0.3 * DEG),
    ])
    return Dataset(frame, clean.meta)


@pytest.mark.parametrize("single", [False, True])
def test_c_weighs_on_a_named_tilt_as_python_does(single, models, tilt_faults, tmp_path):
    """A named house tilt in C: the same degraded statuses while its value from before the fault
    stands in (health.TILT_SUBSTITUTE_LIMIT, the slew bound), the estimates and sigma equal to
    Python's; the models without degraded weighing export none of it."""
    est = models["calibrated-momentum"]
    header, source = export_c(est, tmp_path / "export", precision="float32" if single else "float64")
    assert "ep_hm_tilt_ref" in source.read_text()
    py = _assert_equal(est, source, tilt_faults, tmp_path / "build", single=single)
    degraded = (py["status"] == Status.DEGRADED.value).to_numpy()
    assert degraded.sum() > 100
    assert all("house_" in f for f in py["fault"][degraded])
    text = export_c(models["inverse-dynamics"], tmp_path / "id")[1].read_text()
    assert "ep_hm_tilt_ref" not in text and "hm_house" not in text


def test_c_drops_a_named_pressures_joint_without_the_joint_check_too(models, pressure_faults, tmp_path):
    """``joint_check off``: C still drops a named pressure's joint as Python does (before, the
    export without the check passed no drop to the kernel: its named pressures weighed on)."""
    est = copy.deepcopy(models["calibrated-momentum"])
    est.options["joint_check"] = "off"
    est.use_calibration()
    source = export_c(est, tmp_path / "export")[1]
    assert "ep_jc_status" not in source.read_text() and "&s->hm_drop" in source.read_text()
    py = _assert_equal(est, source, pressure_faults, tmp_path / "build")
    assert (py["status"] == Status.DEGRADED.value).sum() > 100


@pytest.mark.parametrize("name,single", [("calibrated-momentum", False), ("calibrated-momentum", True),
                                         ("inverse-dynamics", False)])
def test_c_names_a_slew_rate_gain_on_a_slope_as_python_does(name, single, models, tmp_path):
    """A slew rate × 0.75 from 5 s on ground tilted about 9° (estimators/health_slew.py): C names
    the slew rate and both tilts ``gain`` at the same samples as Python, and neither names it on
    the clean work."""
    slope = simulate_machine_dataset(1, seed=32, session=2, motion="slopes")
    frame = slope.frame.copy()
    frame.loc[frame.index[500:], "slew_rate"] *= 0.75
    est = models[name]
    source = export_c(est, tmp_path / "export", precision="float32" if single else "float64")[1]
    py = _assert_equal(est, source, Dataset(frame, slope.meta), tmp_path / "build", single=single)
    assert py["fault"].str.contains("slew_rate:gain").sum() > 500
    clean = _assert_equal(est, source, slope, tmp_path / "clean", single=single)
    assert not clean["fault"].str.contains(":gain").any()
