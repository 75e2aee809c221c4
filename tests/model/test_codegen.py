"""The native-code cache never loads a library that is not the one it built."""

import casadi as ca
import numpy as np
import pytest

from excavator_payload.model import codegen


@pytest.fixture
def cache(tmp_path, monkeypatch):
    if codegen.compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("EXCAVATOR_PAYLOAD_CACHE", str(tmp_path))
    return tmp_path / "native"


def _function():
    x = ca.SX.sym("x", 2)
    return ca.Function("guarded_model", [x], [ca.cos(x) * x[1]])


@pytest.mark.parametrize("damage", ["truncate", "flip", "no-checksum", "empty"])
def test_damaged_library_is_rebuilt_not_loaded(cache, damage):
    f = _function()
    library = codegen.compiled_library([f], "guarded_model")
    raw = library.read_bytes()
    if damage == "truncate":
        library.write_bytes(raw[: len(raw) // 3])  # mapping this would SIGBUS the process
    elif damage == "flip":
        library.write_bytes(raw[:100] + bytes(b ^ 0xFF for b in raw[100:200]) + raw[200:])
    elif damage == "no-checksum":
        library.with_name(library.name + ".sha256").unlink()
    else:
        library.write_bytes(b"")
    assert not codegen.verified(library)
    again = codegen.compiled_library([f], "guarded_model")
    assert again == library and codegen.verified(library)
    native = codegen.native(f)
    np.testing.assert_allclose(np.asarray(native([0.3, 0.7])).ravel(), np.cos([0.3, 0.7]) * 0.7)
