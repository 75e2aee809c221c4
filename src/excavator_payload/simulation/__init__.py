"""Simulator: NMPC-driven digging swings, scenarios, sensor noise, dataset generation."""
