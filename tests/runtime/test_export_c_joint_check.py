"""The calibrated kernel's joint check in the C export (runtime/export_c/joint_check.py) equals
Python's (machine_calibration/joint_check.py) sample by sample: statuses, the pressures named
``balance`` (``ep_faults(s, EP_FAULT_BALANCE)``, FMI 13) against ``StepResult.fault``, estimates
(the weighing without the joint named) and ``ep_sigma``; on clean work and with a boom head
pressure offset injected; ``-DEP_HEALTH=0`` runs neither monitor nor check, as ``health = False``;
an export with ``joint_check off`` carries none of it."""

import copy

import pytest

from excavator_payload.data.dataset import Dataset
from excavator_payload.estimators.base import create_estimator
from excavator_payload.runtime.c_harness import c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.machine_sim import simulate_machine_dataset
from tests.runtime.test_export_c_health import BAR, _assert_equal

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")


@pytest.fixture(scope="module")
def model():
    est = create_estimator("calibrated", machine="cat345c-hydraulic-3pct", balance="momentum")
    est.fit(simulate_machine_dataset(3, seed=3))
    est.options["joint_check"] = "on"
    est.options["imu_nuisance"] = "off"  # the check alone (with the filter: test_export_c_imu_nuisance.py)
    est.use_calibration()
    assert est.health and est.kernel.regression._imu_nuisance is None
    return est


@pytest.fixture(scope="module")
def work():
    """Clean operator motion (another seed and session than the fitting data), and the same with
    the boom head pressure 10 bar high from 4 s on in both experiments."""
    clean = simulate_machine_dataset(2, seed=31, session=2, motion="operator")
    frame = clean.frame.copy()
    for e in clean.experiment_ids:
        rows = frame.index[frame["experiment"] == e]
        frame.loc[rows[400:], "boom_head_pressure"] += 10 * BAR
    return clean, Dataset(frame, clean.meta)


def test_c_joint_check_names_an_offset_as_python_does(model, work, tmp_path):
    source = export_c(model, tmp_path / "export")[1]
    assert "ep_jc_update" in source.read_text()
    py = _assert_equal(model, source, work[1], tmp_path / "build")
    named = py["fault"].str.contains("boom_head_pressure:balance", regex=False)
    assert named.sum() > 100 and py["fault"].str.contains("boom_rod_pressure:balance", regex=False).sum() == named.sum()
    assert (py.loc[named, "status"] == "sensor_fault").all()
    row = work[1].frame.groupby("experiment").cumcount().to_numpy()
    assert not named.to_numpy()[row < 400].any()  # nothing named before the offset


def test_c_joint_check_equals_python_on_clean_work(model, work, tmp_path):
    source = export_c(model, tmp_path / "export")[1]
    py = _assert_equal(model, source, work[0], tmp_path / "build")
    assert "ok" in set(py["status"])


def test_float_build_names_the_same(model, work, tmp_path):
    source = export_c(model, tmp_path / "export", precision="float32")[1]
    _assert_equal(model, source, work[1], tmp_path / "build", single=True)


def test_compiled_out_with_the_monitor(model, work, tmp_path):
    """-DEP_HEALTH=0 is ``health = False``: no check either (Estimator._step), no balance fault."""
    est = copy.deepcopy(model)
    source = export_c(est, tmp_path / "export")[1]
    est.health = False
    py = _assert_equal(est, source, work[1], tmp_path / "off", extra_flags=("-DEP_HEALTH=0",))
    assert "sensor_fault" not in set(py["status"])


def test_off_exports_no_check(model, work, tmp_path):
    """``joint_check off``: none of the check's C, and C equals Python without it."""
    est = copy.deepcopy(model)
    est.options["joint_check"] = "off"
    source = export_c(est, tmp_path / "export")[1]
    assert "ep_jc_" not in source.read_text()
    py = _assert_equal(est, source, work[1], tmp_path / "build")
    assert not py["fault"].str.contains("balance").any()



def test_c_suspect_and_monitor_faults_equal_python(model, tmp_path):
    """The rule before a fault is named (JointCheck.suspect: ``load_changing`` while the joints part
    or the weighing moves) in C as in Python, on a boom head pressure 10 bar high for 3 s and then
    a boom rate 30 % high for 2 s; and a sample the monitor keeps from the kernel (the rate's
    offset, named while a balance fault stood) reports only the monitor's faults: C once reported
    the kernel's last balance fault beside them."""
    clean = simulate_machine_dataset(2, seed=32, session=2, motion="operator")
    frame = clean.frame.copy()
    for e in clean.experiment_ids:
        rows = frame.index[frame["experiment"] == e]
        frame.loc[rows[400:700], "boom_head_pressure"] += 10 * BAR
        frame.loc[rows[1000:1200], "boom_rate"] *= 1.3
    source = export_c(model, tmp_path / "export")[1]
    text = source.read_text()
    assert "ep_jc_track_moving" in text and "ep_jc_restart" in text
    py = _assert_equal(model, source, Dataset(frame, clean.meta), tmp_path / "build")
    assert (py["status"] == "load_changing").any()
    fault = py["fault"].astype(str)
    after_balance = fault.shift().str.contains("balance").fillna(False).to_numpy()
    monitor_only = (fault.str.contains(":offset") & ~fault.str.contains("balance")).to_numpy()
    assert (after_balance & monitor_only).any()


def _unchecked(model):
    """A copy of ``model`` with the joint check off (its weighing otherwise the same)."""
    est = copy.deepcopy(model)
    est.options["joint_check"] = "off"
    est.use_calibration()
    return est


def test_a_boom_lift_is_weighed_with_the_check_on(model, tmp_path):
    """A boom lifted alone (dipper and bucket held: the industry's weighing motion) is one joint
    weighed, which the check cannot compare with another: it is weighed `ok` all the same, with
    the estimates and statuses of the check switched off, in Python and C alike (before, every
    sample of a lift said ``warming_up``: the weight never showed)."""
    lifts = simulate_machine_dataset(2, seed=32, session=2, motion="lifts")
    source = export_c(model, tmp_path / "export")[1]
    py = _assert_equal(model, source, lifts, tmp_path / "build")
    unchecked = _unchecked(model).estimate(lifts)
    late = lifts.frame["time"].to_numpy() >= 5.0
    for e in lifts.experiment_ids:
        rows = late & (lifts.frame["experiment"].to_numpy() == e)
        assert (py["status"].to_numpy()[rows] == "ok").mean() > 0.8
    assert (py["status"].to_numpy() == unchecked["status"].astype(str).to_numpy()).all()
    assert py["payload_estimate"].to_numpy() == pytest.approx(unchecked["payload_estimate"].to_numpy(), nan_ok=True)


def test_a_lone_joint_whose_weighing_moves_waits_for_a_second(model, tmp_path):
    """A boom head pressure 25 % high from 10 s into a lift (one joint weighed, nothing to
    compare it with): the weighing moves, and from then on it is not ``ok`` (``warming_up``)
    until a second joint is weighed, which a lift never does — also after the new-load restart
    the jump sets off; C equal to Python."""
    lifts = simulate_machine_dataset(1, seed=33, session=2, motion="lifts")
    frame = lifts.frame.copy()
    onset = 1000
    frame.loc[frame.index[onset:], "boom_head_pressure"] *= 1.25
    faulty = Dataset(frame, lifts.meta)
    source = export_c(model, tmp_path / "export")[1]
    py = _assert_equal(model, source, faulty, tmp_path / "build")
    clean = model.estimate(lifts)
    ok = py["status"].to_numpy() == "ok"
    error = abs(py["payload_estimate"].to_numpy() - frame["payload"].to_numpy())
    clean_ok = clean["status"].astype(str).to_numpy() == "ok"
    clean_error = abs(clean["payload_estimate"].to_numpy() - frame["payload"].to_numpy())
    assert ok[:onset].mean() > 0.5 and clean_ok[onset:].mean() > 0.8
    assert ok[onset:].any()  # the move is not seen at once
    assert error[onset:][ok[onset:]].max() < clean_error[clean_ok].max() + 30.0
    off = _unchecked(model).estimate(faulty)
    off_ok = off["status"].astype(str).to_numpy() == "ok"
    off_error = abs(off["payload_estimate"].to_numpy() - frame["payload"].to_numpy())
    assert off_error[onset:][off_ok[onset:]].max() > clean_error[clean_ok].max() + 100.0  # what the hold keeps out


def test_c_holds_a_slight_joint_as_python_does(model, work, tmp_path):
    """The rule that holds a fault of one joint moving the weighing by little (JointCheck._slight,
    ``EP_JC_SLIGHT_LIMIT``), with its limit raised past any weighing (the kernel's check, which the
    export reads): on a dipper head pressure 5 bar high, which the default limit names as one joint
    (the bucket), no one joint is named, in Python and in C alike, sample by sample."""
    clean = work[0]
    frame = clean.frame.copy()
    for e in clean.experiment_ids:
        rows = frame.index[frame["experiment"] == e]
        frame.loc[rows[400:], "dipper_head_pressure"] += 5 * BAR
    offset = Dataset(frame, clean.meta)
    single = {f"{j}_head_pressure:balance,{j}_rod_pressure:balance" for j in ("boom", "dipper", "bucket")}
    assert model.estimate(offset)["fault"].astype(str).isin(single).sum() > 100  # the default names one
    est = copy.deepcopy(model)
    est.kernel.regression._joints.slight_limit = 1e9
    source = export_c(est, tmp_path / "export")[1]
    assert "EP_JC_SLIGHT_LIMIT" in source.read_text()
    py = _assert_equal(est, source, offset, tmp_path / "build")
    assert not py["fault"].astype(str).isin(single).any()


@pytest.mark.parametrize("dump_restarts", [False, True])
def test_c_restarts_after_a_dumped_load_as_python_does(model, tmp_path, monkeypatch, dump_restarts):
    """A `slopes` work cycle that dumps 239 kg, too little for the new-load test, and then lowers
    the boom alone (the stale joint, docs/findings/false-alarms.md): the check restarts the
    weighing once the boom weighs less after the dump than before it (JointCheck._dumped_load,
    ``ep_jc_dumped_load``), in C as in Python, sample by sample. With the dumps' restarts
    (``settings.DUMP_RESTARTS``, the default) the dump's end restarts it first, in C as in Python."""
    from excavator_payload.estimators.classical.machine_calibration import kernel as kernel_module
    from excavator_payload.estimators.classical.machine_calibration import settings
    from excavator_payload.evaluation import demo_machine as dm

    monkeypatch.setattr(kernel_module, "DUMP_RESTARTS", dump_restarts)
    monkeypatch.setattr(settings, "DUMP_RESTARTS", dump_restarts)
    from excavator_payload.simulation.generate import simulate_dataset

    cycles = simulate_dataset(4, seed=70000, motion="slopes", machine="cat345c-hydraulic", session=dm.SESSION_WORK,
                              with_truth=True, workers=1, progress=False)
    frame = cycles.frame
    small = Dataset(frame[frame["experiment"] == cycles.experiment_ids[3]].reset_index(drop=True), cycles.meta)
    assert small.frame["payload"].iloc[0] < 300.0
    source = export_c(model, tmp_path / "export")[1]
    assert "ep_jc_dumped_load" in source.read_text()
    _assert_equal(model, source, small, tmp_path / "build")
    kernel = model.kernel.regression
    assert (kernel._joints.dumped_loads, kernel.dump_restarts) == ((0, 1) if dump_restarts else (1, 0))


def test_c_clears_a_pair_on_a_new_loads_sums_as_python_does(model, tmp_path):
    """A truck of the `shift` motion on which this small test model names the boom and dipper
    together (two joints compared: nothing weighed): the pair is judged again on a later load's
    sums and cleared when its own two joints agree there (``named_before_load``; before, a pair
    cleared only once all three joints were compared, docs/findings/false-alarms.md), in C as in
    Python, sample by sample."""
    shift = simulate_machine_dataset(1, seed=103, session=2, motion="shift", truck_target=20000.0)
    source = export_c(model, tmp_path / "export")[1]
    assert "jc_named_before_load" in source.read_text()
    py = _assert_equal(model, source, shift, tmp_path / "build")
    assert py["fault"].astype(str).str.count(":balance").max() == 4  # a pair named
    assert model.kernel.regression._joints.cleared_pairs >= 1


@pytest.mark.parametrize("seed", [106, 108])
def test_c_clears_a_pair_on_its_own_sums_or_by_any_two_joints_as_python_does(model, seed, tmp_path):
    """Two trucks of the `shift` motion on which this small test model names joints together and
    the two clearing rules of docs/findings/false-alarms.md ("A pair cleared on its own sums...")
    fire: seed 108's pair (boom and dipper) clears on its own load's sums when its own two agree
    again; seed 106's three joints named together clear at a later load where only boom and dipper
    are compared and agree (before, a pair cleared on the same load only once all three joints
    were compared, and at a new load only when all of its own were). In C as in Python, sample by
    sample."""
    shift = simulate_machine_dataset(1, seed=seed, session=2, motion="shift", truck_target=20000.0)
    source = export_c(model, tmp_path / "export")[1]
    py = _assert_equal(model, source, shift, tmp_path / "build")
    assert py["fault"].astype(str).str.count(":balance").max() >= 4  # a pair (or more) named
    if seed == 106:
        assert model.kernel.regression._joints.cleared_pairs >= 1


def test_c_holds_a_joint_that_agrees_on_one_side_as_python_does(tmp_path, monkeypatch):
    """The traced `slopes` cycle (bench_false_alarms.py seed 83000, experiment 31 of chunk 0: a
    919 kg load) with the study model (10 calibration swings, seed 9200; zeroed on the empty swing):
    the bucket weighed 914 kg in its curl and about 1 800 kg on the far side of its regressor's zero,
    braking to a stop before the weighing was ready, and was named ``balance`` from the weighing's
    readiness to the end (1 843 samples). It agrees with boom and dipper on the near side alone: held
    (JointCheck._side_agrees, ``ep_jc_side_agrees``), nothing named, in C as in Python, sample by
    sample; without the rule Python names the bucket."""
    from excavator_payload.estimators.classical.calibrated import CalibratedEstimator
    from excavator_payload.estimators.classical.machine_calibration.joint_check import JointCheck
    from excavator_payload.evaluation import demo_machine as dm
    from excavator_payload.simulation.generate import simulate_dataset

    est = CalibratedEstimator("cat345c-hydraulic-3pct").fit(dm.calibration_data(10, 9200))
    est.zero(dm.zero_data(9150))
    cycle = simulate_dataset(1, seed=83000 + 8000, motion="slopes", machine="cat345c-hydraulic",
                             session=dm.SESSION_WORK, with_truth=True, workers=1, progress=False,
                             first_experiment=31)
    source = export_c(est, tmp_path / "export")[1]
    assert "ep_jc_side_agrees" in source.read_text()
    py = _assert_equal(est, source, cycle, tmp_path / "build")
    assert not (py["status"] == "sensor_fault").any()
    assert est.kernel.regression._joints.side_holds > 0
    monkeypatch.setattr(JointCheck, "_side_agrees", lambda self, joints, m, w: False)
    named = est.estimate(cycle)["fault"].astype(str).str.contains("bucket_head_pressure:balance", regex=False)
    assert named.sum() > 1000


@pytest.mark.parametrize("pause_restarts", [True, False])
def test_c_restarts_at_a_pauses_end_as_python_does(model, work, tmp_path, monkeypatch, pause_restarts):
    """The clean operator motion's second experiment, on which this small test model's check
    pauses and the memories agree again: the weighing restarts there (``settings.PAUSE_RESTARTS``,
    ``EP_JC_PAUSE_RESTARTS``), in C as in Python, sample by sample; with the rule off neither does."""
    from excavator_payload.estimators.classical.machine_calibration import joint_check as joint_check_module
    from excavator_payload.estimators.classical.machine_calibration import settings

    monkeypatch.setattr(joint_check_module, "PAUSE_RESTARTS", pause_restarts)
    monkeypatch.setattr(settings, "PAUSE_RESTARTS", pause_restarts)
    clean = work[0]
    second = Dataset(clean.frame[clean.frame["experiment"] == clean.experiment_ids[1]].reset_index(drop=True),
                     clean.meta)
    source = export_c(model, tmp_path / "export")[1]
    assert f"#define EP_JC_PAUSE_RESTARTS {int(pause_restarts)}" in source.read_text()
    _assert_equal(model, source, second, tmp_path / "build")
    assert model.kernel.regression._joints.pause_restarts == (1 if pause_restarts else 0)
