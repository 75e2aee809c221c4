"""C export of ``calibrated --imu-nuisance on`` (runtime/export_c/imu_nuisance.py): equals
Python's ``estimate`` (double: 1e-6 relative, float: 0.1 kg), status codes and ``ep_sigma``
included, on faulty data (NaN, gaps, a non-finite state), across a new load and a settle."""

import copy

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.c_harness import c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

from .test_export_c import _assert_c_equals_python
from .test_export_c_machine import machine_faulty, machine_swings  # noqa: F401 (fixtures)

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")


@pytest.fixture(scope="module")
def models(machine_swings):  # noqa: F811
    """The momentum form (the default) fitted on the three swings, option off (the default: auto,
    on) and on."""
    off = create_estimator("calibrated", machine="cat345c-hydraulic-3pct", model_std="none",
                           imu_nuisance="off").fit(machine_swings)
    off.health = False  # the monitor's C is compared in test_export_c_health.py
    on = copy.deepcopy(off)
    on.options["imu_nuisance"] = "on"
    on.use_calibration()
    return {"off": off, "on": on}


def test_c_equals_python_with_the_imu_dynamics_re_estimated(models, machine_faulty, tmp_path):  # noqa: F811
    est = models["on"]
    header, source = export_c(est, tmp_path / "export")
    assert "#define EP_NZ 2" in header.read_text()
    py = None
    for single in (False, True):
        py = _assert_c_equals_python(est, source, machine_faulty, tmp_path / "build", single)
    seen = set(py["status"])
    assert {"ok", "gap", "state_reset"} <= seen
    # the C weighs what Python weighs with the option on, not what it weighs with it off
    off = models["off"].estimate(machine_faulty)["payload_estimate"].to_numpy(float)
    on = py["payload_estimate"].to_numpy(float)
    both = np.isfinite(off) & np.isfinite(on)
    assert both.any() and np.max(np.abs(off[both] - on[both])) > 0.1


@pytest.mark.parametrize("dump_restarts", [False, True])
def test_c_equals_python_across_loads_and_a_settle(models, tmp_path, monkeypatch, dump_restarts):
    """A truck loaded pass after pass: the weighing restarts on each new load (the nuisances
    back at the calibration's) and settles (the short memory's sums) on the same samples; with
    the dumps' restarts (``settings.DUMP_RESTARTS``, the default) it restarts at each dump's end
    instead of settling, in C as in Python."""
    from excavator_payload.estimators.classical.machine_calibration import kernel as kernel_module
    from excavator_payload.estimators.classical.machine_calibration import settings

    monkeypatch.setattr(kernel_module, "DUMP_RESTARTS", dump_restarts)
    monkeypatch.setattr(settings, "DUMP_RESTARTS", dump_restarts)
    truck = simulate_machine_dataset(1, seed=7, session=2, motion="shift", truck_target=12000.0)
    est = models["on"]
    est.reset()
    f = truck.frame
    for t, row in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        est.step_values(t, row)
    kernel = est.kernel.regression
    assert kernel.new_loads >= 1 and (kernel.dump_restarts if dump_restarts else kernel.settles) >= 1
    source = export_c(est, tmp_path / "export")[1]
    for single in (False, True):
        _assert_c_equals_python(est, source, truck, tmp_path / "build", single)


def test_off_exports_the_kernel_as_before(models, tmp_path):
    header, source = export_c(models["off"], tmp_path / "export")
    assert "EP_NZ" not in header.read_text() and "nz_" not in source.read_text()


def test_c_equals_python_with_the_joint_check_beside(models, tmp_path):
    """Both on (the defaults): the check judges the kernel's sums, the weighing reported is the
    filter's (its marginal information in the warm-up test and σ), a named joint's degraded
    weighing the kernel's without it; C equals Python on a truck loaded pass after pass (digs,
    dumps: the dump rule) and on the same with a boom head pressure 10 bar high from the fourth
    second (named: ``ep_faults`` against ``StepResult.fault``)."""
    from tests.runtime.test_export_c_health import BAR, _assert_equal

    both = copy.deepcopy(models["on"])
    both.options["joint_check"] = "on"
    both.health = True
    both.use_calibration()
    assert both.kernel.regression._imu_nuisance is not None
    header, source = export_c(both, tmp_path / "export")
    text = source.read_text()
    assert "ep_jc_update" in text and "EP_JC_WEIGHED_INFO(s) EP_NZ_INFO(s)" in text
    truck = simulate_machine_dataset(1, seed=7, session=2, motion="shift", truck_target=12000.0)
    py = _assert_equal(both, source, truck, tmp_path / "clean")
    # (this three-swing model names sound cylinders too: parity, not silence; its few ok samples,
    # 9 of 8 350, are load_changing since the joint check's suspect rule: the joints part)
    assert "load_changing" in set(py["status"])
    # streaming step equals the batch, and the dumps were seen (the dump rule in both)
    both.reset()
    f = truck.frame
    dumping, streamed = [], []
    for t, row in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        streamed.append(both.step_values(t, row))
        dumping.append(both.kernel.regression.dumping)
    assert [r.status.value for r in streamed] == list(py["status"])
    assert [r.fault for r in streamed] == list(py["fault"])
    assert 0 < sum(dumping) < len(dumping) // 4
    frame = truck.frame.copy()
    frame.loc[frame.index[400:], "boom_head_pressure"] += 10 * BAR
    bad = type(truck)(frame, truck.meta)
    py = _assert_equal(both, source, bad, tmp_path / "bad")
    assert py["fault"].str.contains("boom_head_pressure:balance", regex=False).any()
    _assert_equal(both, source, bad, tmp_path / "float", single=True)
