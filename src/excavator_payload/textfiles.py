"""Reading the small text files a user writes by hand (machine files, signal maps, studies).

Windows editors save them with a byte-order mark (Notepad: UTF-8 with BOM; PowerShell 5's
``>`` and ``Out-File``: UTF-16): TOML allows neither, and both were refused as "Invalid
statement (at line 1, column 1)". They are read as the text they hold.
"""

from __future__ import annotations

import codecs
from pathlib import Path


def read_config_text(path: str | Path, errors: str = "strict") -> str:
    """The text of ``path``: UTF-8 with or without a byte-order mark, or UTF-16 with one.

    Parameters
    ----------
    path : str or Path
        The file.
    errors : str, optional
        How undecodable UTF-8 bytes are handled (``"strict"`` raises UnicodeDecodeError,
        ``"replace"`` keeps going).
    """
    raw = Path(path).read_bytes()
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return raw.decode("utf-16", errors=errors)
    return raw.decode("utf-8-sig", errors=errors)


#: What ``stat`` calls a path that exists but is no regular file (nor folder), in words.
_SPECIAL = (("S_ISFIFO", "a named pipe (FIFO)"), ("S_ISCHR", "a character device"),
            ("S_ISBLK", "a block device"), ("S_ISSOCK", "a socket"))


def not_a_file(path: str | Path, what: str) -> str:
    """Why ``path`` cannot be read as ``what``: ``"… does not exist"``, or, for a path that
    exists but is a named pipe, a device or a socket, that it is one. Reading a named pipe as a
    dataset blocked until another program wrote into it (``estimate --data pipe.parquet`` hung
    forever); the other readers said such a path "does not exist".

    Parameters
    ----------
    path : str or Path
        The path the user gave.
    what : str
        What it should be, the start of the sentence (``"dataset file"``, ``"CAN log"``).

    Returns
    -------
    str
        One sentence for an error line.
    """
    import os
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return f"{what} '{path}' does not exist"
    if stat.S_ISDIR(mode):
        return f"{what} '{path}' is a folder, not a file"
    for test, words in _SPECIAL:
        if getattr(stat, test)(mode):
            return f"{what} '{path}' is {words}, not a file: give the file itself (copy what the pipe or device carries into one)"
    return f"{what} '{path}' is not a regular file"


def is_special(path: str | Path) -> bool:
    """Whether ``path`` exists and is neither a regular file nor a folder (a named pipe, a
    device, a socket): reading it may block for ever.

    Parameters
    ----------
    path : str or Path
        The path the user gave.
    """
    import os
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))
