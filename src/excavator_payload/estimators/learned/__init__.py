"""Estimators learned from recorded data with known loads, with no machine file."""
