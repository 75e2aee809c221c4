"""Evaluation: metrics, the Cramér–Rao bound, figures and the report."""
