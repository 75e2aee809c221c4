"""Datasets: schema, Parquet I/O, validation, MATLAB export."""

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.io import read_dataset, read_estimates, write_dataset, write_estimates
from excavator_payload.data.schema import COLUMNS, SIGNALS, TRUTH_COLUMNS, UNITS

__all__ = ["Dataset", "read_dataset", "write_dataset", "read_estimates", "write_estimates",
           "COLUMNS", "SIGNALS", "TRUTH_COLUMNS", "UNITS"]
