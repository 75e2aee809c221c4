"""Guards on the public API (python-control style): names users import must keep existing."""

import inspect

import excavator_payload
from excavator_payload import data, estimators, model
from excavator_payload.data.schema import COLUMNS, SIGNALS
from excavator_payload.estimators.base import ESTIMATOR_MODULES, Estimator


def test_top_level_names():
    assert excavator_payload.__version__
    for name in ("ArmModel", "Machine", "load_machine", "list_presets", "symbolic"):
        assert hasattr(model, name), name
    for name in ("Dataset", "read_dataset", "write_dataset", "read_estimates", "write_estimates"):
        assert hasattr(data, name), name
    for name in ("Estimator", "create_estimator", "load_estimator", "register", "Status"):
        assert hasattr(estimators, name), name


def test_schema_is_stable():
    assert SIGNALS == ("boom_angle", "boom_rate", "boom_accel", "dipper_angle", "dipper_rate",
                       "dipper_accel", "boom_torque", "dipper_torque")
    assert COLUMNS == ("experiment", "time", *SIGNALS, "payload")


def test_estimator_protocol_signatures():
    for method in ("fit", "estimate", "step", "reset", "save"):
        assert callable(getattr(Estimator, method))
    assert list(inspect.signature(Estimator.fit).parameters) == ["self", "dataset"]
    assert list(inspect.signature(Estimator.estimate).parameters) == ["self", "dataset"]
    assert list(inspect.signature(Estimator.step).parameters) == ["self", "sample"]
    assert list(inspect.signature(Estimator.save).parameters) == ["self", "directory"]


def test_every_registered_estimator_follows_the_protocol():
    for name in ESTIMATOR_MODULES:
        klass = estimators.estimator_class(name)
        assert klass.name == name
        assert issubclass(klass, Estimator)
        for key, opt in klass.OPTIONS.items():
            assert opt.help, f"{name} option {key} has no help"


def test_presets_ship_with_the_package():
    assert {"cat345c", "cat345c-1pct", "cat345c-3pct"} <= set(model.list_presets())
    m = model.load_machine("cat345c")
    assert (m.boom_length, m.boom_mass, m.dipper_length, m.dipper_mass, m.bucket_mass) == (
        6.55, 4600.0, 3.00, 2410.0, 2900.0)
    assert m.boom_friction == m.dipper_friction == 3e5
