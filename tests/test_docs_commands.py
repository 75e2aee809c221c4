"""Every ``excavator-payload`` command the README and the documentation site show parses.

A user copies a command from the docs; an option renamed or removed since (or a value the
option does not take) must fail here, not in their shell. Each command line in a fenced shell
block is parsed by the CLI's own parser (option names, types, choices, the callbacks that
resolve names) without running it, and the names the commands resolve in their body (an
estimator, a machine preset, a motion, a noise preset) are looked up. Optional parts written ``[--opt VALUE]`` are parsed as
given, and ``a|b|c`` alternatives as their first choice.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import typer
from typer._click import exceptions as click_exceptions

from excavator_payload.cli import app
from excavator_payload.estimators.registry import estimator_names
from excavator_payload.model.machine import list_presets
from excavator_payload.platforms.registry import PLATFORMS

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
BLOCK = re.compile(r"```(?:bash|sh|console|shell)?\n(.*?)```", re.S)
COMMAND = re.compile(r"(?:^|\s)excavator-payload\s+(.*)")


def documented_commands(path: Path) -> list[tuple[str, list[str]]]:
    """The ``excavator-payload`` command lines of ``path``'s fenced shell blocks, as
    (line, arguments after the program name).

    Parameters
    ----------
    path : Path
        A Markdown file.
    """
    found = []
    for block in BLOCK.findall(path.read_text(encoding="utf-8")):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.strip()
            match = COMMAND.search(line)
            if not match or line.startswith("#"):
                continue
            rest = re.split(r"\s+#", match.group(1))[0]  # a trailing comment
            rest = re.split(r"\s(?:&&|\|\||\||;|>|2>|<)\s", rest)[0]  # the next command, a redirect
            rest = re.sub(r"\[([^\]]*)\]", r"\1", rest)  # [--opt VALUE]: parsed as given
            args = [a.split("|")[0] if "|" in a and not a.startswith(("-", "'", '"')) else a
                    for a in shlex.split(rest)]
            found.append((line, args))
    return found


def parse_error(args: list[str]) -> str | None:
    """The CLI parser's message for ``args`` (None: they parse).

    Parameters
    ----------
    args : list of str
        The arguments after ``excavator-payload``.
    """
    root = typer.main.get_command(app)
    if not args or args[0].startswith("-"):
        return None if not args or args[0] in ("--help", "--version") else f"no command in {args}"
    command = root.commands.get(args[0])
    if command is None:
        return f"no command {args[0]!r}"
    try:
        ctx = command.make_context(args[0], list(args[1:]))
    except click_exceptions.ClickException as error:
        return error.format_message()
    return unknown_name(args[0], ctx.params)


def unknown_name(command: str, params: dict) -> str | None:
    """What in ``params`` names nothing the package knows (None: every name resolves).

    Parameters
    ----------
    command : str
        The command's name.
    params : dict
        Its parsed parameters.
    """
    motions = {m for p in PLATFORMS.values() for m in p.motions}
    noises = {n for p in PLATFORMS.values() for n in p.noise_presets}
    name = params.get("name") or params.get("estimator")
    if command in ("train", "estimators") and isinstance(name, str) and name not in estimator_names():
        return f"no estimator {name!r}"
    machine = params.get("machine")
    if isinstance(machine, str) and not machine.endswith(".toml") and machine not in list_presets():
        return f"no machine preset {machine!r}"
    if isinstance(params.get("motion"), str) and params["motion"] not in motions:
        return f"no motion {params['motion']!r}"
    if isinstance(params.get("noise"), str) and params["noise"] not in noises:
        return f"no noise preset {params['noise']!r}"
    return None


COMMANDS = [(path.relative_to(ROOT).as_posix(), line, args) for path in DOCS
            for line, args in documented_commands(path)]


def test_the_docs_show_commands():
    assert len(COMMANDS) >= 50, len(COMMANDS)
    assert {args[0] for _, _, args in COMMANDS} >= {"demo", "simulate", "train", "zero", "estimate", "evaluate",
                                                  "loadout", "can-replay", "export"}


@pytest.mark.parametrize("where,line,args", COMMANDS, ids=[f"{w}:{i}" for i, (w, _, _) in enumerate(COMMANDS)])
def test_a_documented_command_parses(where, line, args):
    assert parse_error(args) is None, f"{where}: {line}\n{parse_error(args)}"


@pytest.mark.parametrize("line", [
    "excavator-payload simulate --out d.parquet --experimentz 5",   # misspelt option
    "excavator-payload simulate --out d.parquet -n five",          # not a number
    "excavator-payload train calibrated --data d.parquet",         # --out missing
    "excavator-payload weigh --data d.parquet",                    # no such command
    "excavator-payload train calibratd --data d.parquet --out m",  # no such estimator
    "excavator-payload simulate --out d.parquet --machine cat354c",  # no such machine
    "excavator-payload simulate --out d.parquet --motion swings",  # no such motion
    "excavator-payload simulate --out d.parquet --noise feild",    # no such noise preset
])
def test_a_wrong_command_is_caught(tmp_path, line):
    doc = tmp_path / "page.md"
    doc.write_text(f"Text.\n\n```bash\n{line}  # a comment\n```\n", encoding="utf-8")
    ((_, args),) = documented_commands(doc)
    assert parse_error(args) is not None
