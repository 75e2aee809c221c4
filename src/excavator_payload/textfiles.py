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
