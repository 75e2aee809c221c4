"""C export: compiles cleanly under strict C99, equals Python's estimate (double: 1e-6 relative,
float: 0.1 kg), status codes included, on simulated experiments with faults injected."""

import re

import numpy as np
import pytest

from excavator_payload.cli import main
from excavator_payload.data.dataset import Dataset
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.base import Status, create_estimator
from excavator_payload.runtime.c_harness import build, c_compiler
from excavator_payload.runtime.export_c import export_c
from excavator_payload.simulation.generate import simulate_dataset

pytestmark = pytest.mark.skipif(c_compiler() is None, reason="no C compiler on this machine")

CODES = {s.value: i for i, s in enumerate(Status)}
NET = dict(train_experiments=3, validation_experiments=1, epochs=3, progress=False)


@pytest.fixture(scope="module")
def swings():
    """Four NMPC swings (thesis noise)."""
    return simulate_dataset(4, seed=8, workers=1, noise="thesis", progress=False)


@pytest.fixture(scope="module")
def faulty(swings):
    """The swings with every kind of bad sample: NaN, an angle out of range, a repeated time,
    a short gap (0.2 s) and a long one (2 s)."""
    frame = swings.frame.copy()
    ids = list(swings.experiment_ids)
    rows = {e: frame.index[frame["experiment"] == e] for e in ids}
    frame.loc[rows[ids[0]][30], "boom_torque"] = np.nan
    frame.loc[rows[ids[0]][50], "dipper_angle"] = 1.0          # dipper range is -150°…-15°
    frame.loc[rows[ids[1]][40], "time"] = frame.loc[rows[ids[1]][39], "time"]
    drop = list(rows[ids[2]][60:63]) + list(rows[ids[3]][20:60])
    frame = frame.drop(index=drop).reset_index(drop=True)
    return Dataset(frame, swings.meta)


def _models(swings):
    yield "inverse-dynamics", create_estimator("inverse-dynamics").fit(swings)
    yield "calibrated", create_estimator("calibrated", machine="cat345c-3pct").fit(swings)
    yield "ekf", create_estimator("ekf").fit(swings)
    yield "ekf-thesis", create_estimator("ekf", tuning="thesis").fit(swings)
    yield "net1", create_estimator("net1", **NET).fit(swings)
    yield "net2", create_estimator("net2", **NET).fit(swings)


@pytest.fixture(scope="module")
def models(swings):
    return dict(_models(swings))


@pytest.mark.parametrize("name", ["inverse-dynamics", "calibrated", "ekf", "ekf-thesis", "net1", "net2"])
def test_c_equals_python(name, models, faulty, tmp_path):
    est = models[name]
    paths = export_c(est, tmp_path / "export")
    py = est.estimate(faulty)
    want = py["payload_estimate"].to_numpy()
    want_status = np.array([CODES[s] for s in py["status"]])
    assert len(set(want_status)) >= 4  # the faults exercise several statuses
    for single, tol in ((False, None), (True, 0.1)):
        got, status = build(paths[1], tmp_path / "build", single=single).run(faulty)
        np.testing.assert_array_equal(status, want_status)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        ok = ~np.isnan(want)
        if tol is None:
            np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6, atol=1e-6)
        else:
            assert np.abs(got[ok] - want[ok]).max() <= tol


def test_interface_and_purity(models, tmp_path):
    est = models["net1"]
    header, source = export_c(est, tmp_path, precision="float32")
    h, c = header.read_text(), source.read_text()
    assert "#define EP_SINGLE 1" in h and "typedef float ep_real;" in h
    assert f"#define EP_N_SIGNALS {len(est.sensor_set.signals)}" in h
    names = re.search(r"EP_SIGNAL_NAMES\[EP_N_SIGNALS\] = \{(.*)\};", c).group(1)
    assert [n.strip().strip('"') for n in names.split(",")] == list(est.sensor_set.signals)
    for i, s in enumerate(Status):
        assert f"#define EP_STATUS_{s.name} {i}" in h
    for text in (h, c):
        includes = re.findall(r"#include\s*[<\"](.*)[>\"]", text)
        assert set(includes) <= {"math.h", "ep_net1.h"}
        assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", text)
    # the generated CasADi code leaves no public symbol behind
    c_id = export_c(models["ekf"], tmp_path / "ekf")[1].read_text()
    public = re.findall(r"^(?!static)(?:int|void|double|float|ep_real|const) [\w *]*\w+\(", c_id, re.M)
    assert sorted(p.split("(")[0].split()[-1] for p in public) == ["ep_reset", "ep_step"]


def test_export_errors_and_cli(models, swings, tmp_path):
    ukf = create_estimator("ukf").fit(swings)
    with pytest.raises(EstimatorError, match="has no C export"):
        export_c(ukf, tmp_path)
    model = tmp_path / "model"
    models["inverse-dynamics"].save(model)
    out = tmp_path / "c"
    assert main(["export", "--model", str(model), "--format", "c", "--out", str(out)]) == 0
    assert (out / "ep_inverse_dynamics.c").is_file() and (out / "ep_inverse_dynamics.h").is_file()
    assert main(["export", "--model", str(model), "--format", "c", "--out", str(out),
                 "--precision", "half"]) == 2
    assert main(["export", "--model", str(model), "--format", "pdf", "--out", str(out)]) == 2
    assert main(["export", "--model", str(model), "--format", "onnx", "--out", str(out)]) == 2
