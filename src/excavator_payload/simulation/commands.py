"""Command-line commands of this role (registered into :mod:`excavator_payload.cli`)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add this role's commands to ``app``."""
