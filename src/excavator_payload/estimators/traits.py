"""Each estimator's facts, declared once: name, label, module, sensor sets, bound window,
exports, whether it needs a training set (in the spirit of scikit-learn's estimator tags).

Every list the package keeps of its estimators is derived from :data:`ESTIMATOR_TRAITS`: the
registry (:func:`~excavator_payload.estimators.base.estimator_names`, the module each class
is imported from on demand), the Cramér–Rao windows (``metrics.BOUND_WINDOWS``), the table
labels (``metrics.display_label``), what exports where (``runtime.exportable``, checked
against the builders the exporters register), the machine demo's roster and its networks, the
CLI help and the conformance suite. Each estimator class carries its entry as ``TRAITS``
(set from its ``name`` when the class is defined). The table lives here, not in the classes'
modules, so that listing the estimators imports neither torch nor CasADi.

To add an estimator: write its class (``name = "..."``, ``@register``) and add one entry here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from excavator_payload.platforms import HYDRAULIC, THESIS

#: Both sensor sets (:data:`~excavator_payload.data.schema.SENSOR_SETS`).
BOTH = (THESIS.sensors.name, HYDRAULIC.sensors.name)
#: Export formats an estimator may declare.
FORMATS = ("c", "onnx")


@dataclass(frozen=True)
class EstimatorTraits:
    """The facts of one estimator.

    Parameters
    ----------
    name : str
        Registry name, as used on the command line.
    module : str
        The module that defines (and registers) the class, imported on demand.
    label : str
        Its name in tables and reports; empty: the registry name.
    thesis_name : bool
        The label is the thesis' own name (``Net1``): tables show it without the machine.
    sensor_sets : tuple of str
        The sensor sets it runs on.
    bound_window : int or None
        Samples of information it uses, for the Cramér–Rao bound when its options do not say
        (``None``: the whole history).
    exports : dict of str to tuple of str
        Export format (``c``, ``onnx``) -> the sensor sets on which a model fitted exports.
    needs_training_set : bool
        It learns from a training set (hundreds of motions), not from a few calibration ones.
    """

    name: str
    module: str
    label: str = ""
    thesis_name: bool = False
    sensor_sets: tuple[str, ...] = BOTH
    bound_window: int | None = None
    exports: dict[str, tuple[str, ...]] = field(default_factory=dict, hash=False)
    needs_training_set: bool = False

    def __post_init__(self) -> None:
        if not self.label:
            object.__setattr__(self, "label", self.name)
        unknown = set(self.exports) - set(FORMATS)
        if unknown:
            raise ValueError(f"{self.name}: unknown export format(s) {sorted(unknown)}")

    def exports_to(self, fmt: str, sensor_set: str | None = None) -> bool:
        """Whether a fitted model exports as ``fmt``.

        Parameters
        ----------
        fmt : str
            ``c`` or ``onnx``.
        sensor_set : str, optional
            Fitted on this sensor set; None: on any.
        """
        sets = self.exports.get(fmt, ())
        return bool(sets) if sensor_set is None else sensor_set in sets


_CLASSICAL = "excavator_payload.estimators.classical."
_DVS = "excavator_payload.estimators.dvs."
_C_BOTH = {"c": BOTH}
_NET_EXPORTS = {"c": (THESIS.sensors.name,), "onnx": BOTH}

#: Every estimator, in the registry's order (``estimator_names``, the CLI help).
ESTIMATOR_TRAITS: dict[str, EstimatorTraits] = {t.name: t for t in (
    EstimatorTraits("ekf", _CLASSICAL + "ekf", label="EKF_tuned", exports=_C_BOTH),
    EstimatorTraits("ukf", _CLASSICAL + "ukf"),
    EstimatorTraits("inverse-dynamics", _CLASSICAL + "inverse_dynamics", exports=_C_BOTH),
    EstimatorTraits("calibrated", _CLASSICAL + "calibrated", exports=_C_BOTH),
    EstimatorTraits("quasi-static", _CLASSICAL + "quasi_static"),
    # a focused time-delay net with delays 0…5 (thesis Net₁) sees the last 6 samples
    EstimatorTraits("net1", _DVS + "networks", label="Net1", thesis_name=True, bound_window=6,
                    exports=_NET_EXPORTS, needs_training_set=True),
    # NARX and layer-recurrent nets carry state: the whole history
    EstimatorTraits("net2", _DVS + "recurrent", label="Net2", thesis_name=True,
                    exports=_NET_EXPORTS, needs_training_set=True),
    # a feed-forward net sees only the current sample
    EstimatorTraits("ffnn", _DVS + "networks", bound_window=1, exports=_NET_EXPORTS,
                    needs_training_set=True),
    EstimatorTraits("dtdnn", _DVS + "networks", bound_window=6, needs_training_set=True),
    EstimatorTraits("lrn", _DVS + "recurrent", needs_training_set=True),
)}


def traits_of(name: str) -> EstimatorTraits | None:
    """The traits of estimator ``name``, None for a name not in the table (a test's own).

    Parameters
    ----------
    name : str
        Registry name.
    """
    return ESTIMATOR_TRAITS.get(name)


def estimators_on(sensor_set: str) -> tuple[str, ...]:
    """Names of the estimators that run on ``sensor_set``, in registry order.

    Parameters
    ----------
    sensor_set : str
        A sensor set's name.
    """
    return tuple(n for n, t in ESTIMATOR_TRAITS.items() if sensor_set in t.sensor_sets)


def exportable(fmt: str, sensor_set: str | None = None) -> tuple[str, ...]:
    """Names of the estimators that export as ``fmt``, in registry order.

    Parameters
    ----------
    fmt : str
        ``c`` or ``onnx``.
    sensor_set : str, optional
        Fitted on this sensor set; None: on any.
    """
    return tuple(n for n, t in ESTIMATOR_TRAITS.items() if t.exports_to(fmt, sensor_set))
