"""Hand-written text files as a Windows editor saves them."""

import codecs

import pytest

from excavator_payload.textfiles import read_config_text


@pytest.mark.parametrize("raw", [
    "a = 'ü'\n".encode("utf-8"),
    codecs.BOM_UTF8 + "a = 'ü'\n".encode("utf-8"),
    "a = 'ü'\n".encode("utf-16"),  # with its BOM (little-endian here)
    codecs.BOM_UTF16_BE + "a = 'ü'\n".encode("utf-16-be"),
])
def test_the_text_is_the_same_whatever_the_editor_saved(tmp_path, raw):
    path = tmp_path / "x.toml"
    path.write_bytes(raw)
    assert read_config_text(path) == "a = 'ü'\n"


def test_latin1_is_refused_or_replaced_as_asked(tmp_path):
    path = tmp_path / "x.toml"
    path.write_bytes("a = 'ü'\n".encode("latin-1"))
    with pytest.raises(UnicodeDecodeError):
        read_config_text(path)
    assert read_config_text(path, errors="replace") == "a = '\ufffd'\n"
