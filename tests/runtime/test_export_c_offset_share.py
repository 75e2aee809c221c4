"""C export of the zero's share of σ per estimate (runtime/export_c/offset_share.py): after a
zero, the momentum form's ``ep_sigma`` equals Python's (double: 1e-6 relative, float: 1e-4),
with the IMU nuisance filter off and on (the default), on faulty data, across new loads and
settles, and beside the joint check; an unzeroed model exports no share."""

import copy

import numpy as np
import pytest

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.runtime.c_harness import c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.machine_sim import simulate_machine_dataset

from .._machine_data import zeroed_momentum_models
from .test_export_c import _assert_c_equals_python
from .test_export_c_machine import machine_faulty, machine_swings  # noqa: F401 (fixtures)

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")


@pytest.fixture(scope="module")
def models(machine_swings):  # noqa: F811
    """The momentum form fitted on the three swings (no cross-check: s = 0, so σ beyond the
    sensor noise is the zero's share alone), unzeroed and zeroed, the IMU filter off and on."""
    return zeroed_momentum_models(machine_swings)


def _dump_restarts(monkeypatch, on: bool) -> None:
    """``settings.DUMP_RESTARTS`` for the kernel and the C export alike (off: the settles this truck
    has without the dumps' restarts)."""
    from excavator_payload.estimators.classical.machine_calibration import kernel as kernel_module
    from excavator_payload.estimators.classical.machine_calibration import settings

    monkeypatch.setattr(kernel_module, "DUMP_RESTARTS", on)
    monkeypatch.setattr(settings, "DUMP_RESTARTS", on)


@pytest.fixture(scope="module")
def truck():
    """A truck loaded pass after pass: new loads and settles."""
    return simulate_machine_dataset(1, seed=7, session=2, motion="shift", truck_target=12000.0)


@pytest.mark.parametrize("dump_restarts", [False, True])
@pytest.mark.parametrize("nuisance", ["off", "on"])
def test_c_sigma_equals_python_with_the_zeros_share(models, machine_faulty, truck, nuisance, dump_restarts,
                                                     tmp_path, monkeypatch):  # noqa: F811
    _dump_restarts(monkeypatch, dump_restarts)
    est = models[nuisance]
    kernel = est.kernel.regression
    assert kernel._offset_share is not None and (kernel._imu_nuisance is not None) == (nuisance == "on")
    header, source = export_c(est, tmp_path / "export")
    assert "#define EP_OS 11" in header.read_text() and "s->os_std * s->os_std" in source.read_text()
    for single in (False, True):
        py = _assert_c_equals_python(est, source, machine_faulty, tmp_path / "build", single)
    assert {"ok", "gap", "state_reset"} <= set(py["status"])
    est.reset()
    f = truck.frame
    for t, row in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        est.step_values(t, row)
    assert kernel.new_loads >= 1 and (kernel.dump_restarts if dump_restarts else kernel.settles) >= 1
    for single in (False, True):
        py = _assert_c_equals_python(est, source, truck, tmp_path / "truck", single)
    # the share is in the σ compared: without it σ would be the sensor noise's alone (s = 0 here)
    est.reset()
    shares, infos = [], []
    for t, row in zip(f["time"].to_numpy(float), f[list(MACHINE_SENSORS.signals)].to_numpy(float)):
        result = est.step_values(t, row)
        if result.status.value == "ok":
            shares.append(kernel.extra_std)
            infos.append(est.kernel.info)
    assert len(shares) > 100 and np.median(shares) > 0.5 * np.median(1.0 / np.sqrt(infos))


def test_c_sigma_equals_python_beside_the_joint_check(models, truck, tmp_path):
    from tests.runtime.test_export_c_health import _assert_equal

    both = copy.deepcopy(models["on"])
    both.options["joint_check"] = "on"
    both.health = True
    both.use_calibration()
    source = export_c(both, tmp_path / "export")[1]
    text = source.read_text()
    assert "ep_jc_update" in text and "s->os_std * s->os_std" in text
    _assert_equal(both, source, truck, tmp_path / "clean")
    _assert_equal(both, source, truck, tmp_path / "float", single=True)


def test_unzeroed_model_exports_no_share(models, tmp_path):
    assert models["unzeroed"].kernel.regression._offset_share is None
    header, source = export_c(models["unzeroed"], tmp_path / "export")
    assert "EP_OS" not in header.read_text() and "os_" not in source.read_text()
