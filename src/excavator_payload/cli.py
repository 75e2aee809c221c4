"""The ``excavator-payload`` command.

Each role registers its own sub-commands (``simulation/commands.py``,
``estimators/commands.py``, ``evaluation/commands.py``) so that the command modules stay next to
the code they drive; this module only assembles them and turns user errors into one clear
message instead of a traceback.
"""

from __future__ import annotations

import os
import sys
import tempfile
import traceback
from pathlib import Path

import typer
from typer._click.exceptions import ClickException  # typer vendors its own click
from typer.exceptions import Abort
from rich.console import Console
from rich.text import Text

from excavator_payload import __version__
from excavator_payload.errors import ExcavatorPayloadError

app = typer.Typer(
    name="excavator-payload",
    help="Weigh the payload in an excavator's bucket while the arm moves: simulate, train "
    "virtual sensors, estimate, evaluate.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain help: flags show as flags (rich help printed them as "<bool>").
    rich_markup_mode=None,
)
# Console scripts call main(); it must hand its return code to the shell.
err_console = Console(stderr=True)


def _print_version(value: bool) -> None:
    # An eager parameter callback runs before click looks for a command.
    if value:
        typer.echo(f"excavator-payload {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True,
                                 callback=_print_version, expose_value=False),
) -> None:
    """Weigh the payload in an excavator's bucket while the arm moves."""


@app.command()
def machines(
    show: str = typer.Argument(None, help="Print this machine (preset name or TOML file) as a TOML "
                               "machine file, a template for your own."),
) -> None:
    """List the machine presets, or print one as a machine file.

    \f
    Parameters
    ----------
    show : str, optional
        A machine preset name or TOML file to print as a machine file; None: list the presets.
    """
    from excavator_payload.model.machine import list_presets, load_machine
    from excavator_payload.platforms import platform_for

    if show is None:
        names = list_presets()
        width = max(len(n) for n in names)
        for name in names:
            m = load_machine(name)
            kind = platform_for(m).kind  # thesis arm or hydraulic machine (issue 11)
            typer.echo(f"{name:{width}s}  {kind:9s}  {m.description}")
        return
    typer.echo(load_machine(show).to_toml(), nl=False)


def _register_commands() -> None:
    from excavator_payload.estimators import commands as estimator_commands
    from excavator_payload.evaluation import commands as evaluation_commands
    from excavator_payload.evaluation import study_commands
    from excavator_payload.runtime import commands as runtime_commands
    from excavator_payload.simulation import commands as simulation_commands

    simulation_commands.register(app)
    from excavator_payload.evaluation import plot_commands  # issue 11: hydraulic machine plot

    plot_commands.register(app)
    estimator_commands.register(app)
    evaluation_commands.register(app)
    study_commands.register(app)
    runtime_commands.register(app)
    from excavator_payload.estimators import zero_commands  # issue 12: check zero

    zero_commands.register(app)


_register_commands()


def error_line(message: str) -> None:
    """Print one ``error:`` line on stderr; the message is text, never rich markup.

    Parameters
    ----------
    message : str
        The message; its whitespace is collapsed to single spaces.
    """
    err_console.print(Text.assemble(("error:", "bold red"), " ", " ".join(str(message).split())),
                      soft_wrap=True)


def tolerate_narrow_encodings() -> None:
    """Let stdout and stderr replace what their encoding cannot show (a C, latin-1 or cp1252
    console: the tables' "—", "σ" and "≤" raised UnicodeEncodeError, an internal error after
    the work was done) instead of failing; a UTF-8 terminal is left as it is."""
    for stream in (sys.stdout, sys.stderr):
        encoding = (getattr(stream, "encoding", None) or "").lower().replace("-", "").replace("_", "")
        if encoding and encoding not in ("utf8", "utf8sig") and hasattr(stream, "reconfigure"):
            try:
                stream.reconfigure(errors="replace")
            except (ValueError, OSError):  # a closed or detached stream: nothing to show anyway
                pass


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI; user errors print one line and exit with status 2.

    Parameters
    ----------
    argv : list of str, optional
        The command-line arguments (without the program name); None: ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit status: 0 success, 2 user error, 1 internal error, 130 interrupted.
    """
    tolerate_narrow_encodings()
    try:
        code = app(args=argv, standalone_mode=False)
        if code == 130:  # typer turns Ctrl-C into a silent exit status 130
            return _interrupted()
        return code if isinstance(code, int) else 0
    except (Abort, KeyboardInterrupt):
        return _interrupted()
    except ClickException as exc:  # usage errors: typer/click's own one-line message
        exc.show()
        return exc.exit_code
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except ExcavatorPayloadError as exc:
        error_line(str(exc))
        return 2
    except OSError as exc:  # a path the user gave cannot be read or written
        where = f" ('{exc.filename}')" if getattr(exc, "filename", None) else ""
        if not where and isinstance(exc, FileNotFoundError) and not _cwd_exists():
            where = " (the current folder was deleted: cd to one that exists, or give absolute paths)"
        error_line(f"{exc.strerror or type(exc).__name__}{where}")
        return 2
    except UnicodeEncodeError as exc:
        # a non-UTF-8 locale (LC_ALL=C with PYTHONUTF8=0, a latin-1 system): a path with "ü" reaches
        # us as undecodable bytes, which pyarrow and the text files cannot write
        error_line(f"a path or text cannot be encoded in this locale ({exc.encoding}: {exc.reason}); run with a "
                   "UTF-8 locale (LANG=C.UTF-8) or PYTHONUTF8=1, or use ASCII paths")
        return 2
    except MemoryError:
        error_line("out of memory: use smaller data or a smaller model")
        return 2
    except Exception as exc:  # a bug of ours: keep the details in a file, show one line
        log = Path(tempfile.gettempdir()) / "excavator-payload-crash.log"
        try:
            log.write_text(traceback.format_exc())
        except OSError:
            log = Path("(could not write the crash log)")
        err_console.print(Text.assemble(("internal error:", "bold red"),
                                        f" {type(exc).__name__}: {exc} (details in {log}; please report it)"),
                          soft_wrap=True)
        return 1


def _cwd_exists() -> bool:
    try:
        os.getcwd()
        return True
    except OSError:
        return False


def _interrupted() -> int:
    err_console.print(Text.assemble(("interrupted", "red"),
                                    " (no file was left half-written; what was saved before,"
                                    " such as a shift's recorded trucks, is kept)"))
    return 130


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    run()
