"""What ``export`` writes, for which estimators: the tables derived from the estimators' traits
(:mod:`excavator_payload.estimators.traits`) that the exporters' refusals and ``export --help``
read (light to import: no torch, no CasADi, so the CLI's help can list them)."""

from __future__ import annotations

from excavator_payload.estimators.traits import exportable
from excavator_payload.platforms import HYDRAULIC, THESIS

#: Estimators with a C export (:mod:`excavator_payload.runtime.export_c`) on the thesis sensor
#: set, from their traits (as every table here).
C_EXPORTABLE = exportable("c", THESIS.sensors.name)
#: Estimators with a C export on the machine sensor set.
C_EXPORTABLE_MACHINE = exportable("c", HYDRAULIC.sensors.name)
#: Estimators with an ONNX export (:mod:`excavator_payload.runtime.export_onnx`).
ONNX_EXPORTABLE = exportable("onnx")


def per_sample_options(est) -> list[str]:
    """The options of a network that stop it from being exported, as given to ``train``
    (``--decimation 5``, ``--smoothing 0.3``): an export runs the network alone on every sample,
    so only ``--decimation 1 --smoothing 0`` export. Empty for every other estimator.

    Parameters
    ----------
    est : Estimator
        Any estimator (only networks' ``decimation`` and ``smoothing`` count).
    """
    offending = []
    decimation = getattr(est, "decimation", 1)
    if decimation != 1:
        offending.append(f"--decimation {decimation}")
    smoothing = getattr(est, "smoothing", 0.0)
    if smoothing != 0.0:
        offending.append(f"--smoothing {smoothing:g}")
    return offending


def per_sample_refusal(est, fmt: str) -> str | None:
    """The one-line refusal of exporting ``est`` as ``fmt`` (``C`` or ``ONNX``) for the options
    that stop it (:func:`per_sample_options`), else ``None``.

    Parameters
    ----------
    est : Estimator
        Any estimator.
    fmt : str
        The format's name as shown in the message (``C`` or ``ONNX``).
    """
    offending = per_sample_options(est)
    if not offending:
        return None
    return (f"{est.name}: a network trained with {' and '.join(offending)} has no {fmt} export (it runs "
            "the network alone on every sample); train it with --decimation 1 --smoothing 0 to export it")


def format_help() -> str:
    """``export --format``'s help: the formats and what each exports."""
    return (f"c ({', '.join(C_EXPORTABLE)}; on the machine sensor set: {', '.join(C_EXPORTABLE_MACHINE)}) "
            f"or onnx ({', '.join(ONNX_EXPORTABLE)}).")
