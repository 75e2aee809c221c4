"""Datasets: schema, Parquet I/O, validation, MATLAB export."""

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset, read_estimates, write_dataset, write_estimates
from excavator_payload.data.schema import (
    COLUMNS,
    MACHINE_SENSORS,
    SENSOR_SETS,
    SIGNALS,
    THESIS_SENSORS,
    TRUTH_COLUMNS,
    UNITS,
    SensorSet,
    get_sensor_set,
)

__all__ = ["Dataset", "read_dataset", "write_dataset", "read_estimates", "write_estimates",
           "SensorSet", "SENSOR_SETS", "THESIS_SENSORS", "MACHINE_SENSORS", "get_sensor_set",
           "COLUMNS", "SIGNALS", "TRUTH_COLUMNS", "UNITS"]
