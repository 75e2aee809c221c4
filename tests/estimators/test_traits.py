"""Estimator traits (estimators/traits.py): each estimator's facts declared once, and every list
derived from them agrees with what the code really does."""

import subprocess
import sys

import pytest

from excavator_payload.estimators.base import ESTIMATOR_MODULES, estimator_class, estimator_names
from excavator_payload.estimators.traits import ESTIMATOR_TRAITS, FORMATS, EstimatorTraits
from excavator_payload.evaluation.demo_machine import NEEDS_TRAINING_SET, machine_estimators
from excavator_payload.evaluation.metrics import bound_window, display_label


@pytest.mark.parametrize("name", list(ESTIMATOR_TRAITS))
def test_each_class_carries_its_traits(name):
    """The class registered under the name lives in the module the traits name, carries them and
    runs on their sensor sets; a network (no machine) is what needs a training set."""
    klass = estimator_class(name)
    traits = ESTIMATOR_TRAITS[name]
    assert klass.name == name and klass.TRAITS is traits
    assert klass.__module__ == traits.module == ESTIMATOR_MODULES[name]
    assert klass.SENSOR_SETS == traits.sensor_sets
    assert traits.needs_training_set == (not klass.NEEDS_MACHINE)


def test_the_exports_declared_are_the_builders_registered():
    """The one check that the exporters' registrations and the traits agree: a C builder for
    each sensor set the traits list under ``c``, an ONNX graph for each ``onnx`` estimator, and
    nothing registered for an estimator that does not declare it."""
    from excavator_payload.runtime.export_c.registry import registered
    import excavator_payload.runtime.export_onnx  # noqa: F401 (registers every graph)
    from excavator_payload.runtime.onnx_registry import registered as onnx_registered

    c = registered()
    assert set(c) <= set(ESTIMATOR_TRAITS) and set(onnx_registered()) <= set(ESTIMATOR_TRAITS)
    for name, traits in ESTIMATOR_TRAITS.items():
        assert sorted(c.get(name, ())) == sorted(traits.exports.get("c", ())), name
        assert (name in onnx_registered()) == traits.exports_to("onnx"), name


def test_derived_lists():
    assert estimator_names() == list(ESTIMATOR_TRAITS)
    assert machine_estimators() == [n for n in ESTIMATOR_TRAITS if "machine" in estimator_class(n).SENSOR_SETS]
    assert set(NEEDS_TRAINING_SET) == {"net1", "net2", "ffnn", "dtdnn", "lrn", "balance-net"}
    assert bound_window("net1") == 6 and bound_window("ffnn") == 1 and bound_window("ekf") is None
    assert bound_window("net1", {"delays": 9}) == 10
    assert (display_label("net1"), display_label("net2"), display_label("ekf")) == ("Net1", "Net2", "EKF_tuned")
    assert display_label("net1", {}, "cat345c-3pct") == "Net1"  # the thesis' own names stand alone
    assert display_label("ekf", {}, "cat345c-3pct") == "EKF_tuned (cat345c-3pct)"
    assert display_label("ukf", {}, "cat345c") == "ukf" and display_label("someone-else") == "someone-else"


def test_a_wrong_declaration_is_refused():
    with pytest.raises(ValueError, match="unknown export format"):
        EstimatorTraits("x", "m", exports={"pdf": ("thesis",)})
    assert set(FORMATS) == {"c", "onnx"}


def test_listing_the_estimators_imports_neither_torch_nor_casadi():
    """The CLI's help and the export tables read the traits without the estimators' dependencies."""
    code = ("import sys\n"
            "from excavator_payload.estimators.traits import ESTIMATOR_TRAITS\n"
            "from excavator_payload.runtime.exportable import format_help\n"
            "format_help()\n"
            "print(sorted(m for m in ('torch', 'casadi', 'pandas') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
