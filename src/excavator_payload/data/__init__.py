"""Datasets: schema, Parquet I/O, validation, MATLAB export."""

import importlib

# Names are imported when first used (PEP 562): ``import excavator_payload.data.schema`` must not
# pay for pandas and pyarrow (every command's start, --help too).
_WHERE = {"Dataset": "dataset", "read_dataset": "io", "read_estimates": "io", "write_dataset": "io",
          "write_estimates": "io", **{n: "schema" for n in (
              "COLUMNS", "MACHINE_SENSORS", "SENSOR_SETS", "SIGNALS", "THESIS_SENSORS", "TRUTH_COLUMNS",
              "UNITS", "SensorSet", "get_sensor_set")}}

__all__ = ["Dataset", "read_dataset", "write_dataset", "read_estimates", "write_estimates",
           "SensorSet", "SENSOR_SETS", "THESIS_SENSORS", "MACHINE_SENSORS", "get_sensor_set",
           "COLUMNS", "SIGNALS", "TRUTH_COLUMNS", "UNITS"]


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
