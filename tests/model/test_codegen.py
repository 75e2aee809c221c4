"""Native code: the cache never loads a library that is not the one it built; ColumnMap gives
CasADi's own numbers."""

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


def test_column_map_equals_casadi_map_bit_for_bit():
    """ColumnMap (buffer interface) gives the mapped function's own numbers, dense where the
    output is sparse (a Jacobian with structural zeros), a 1-d input shared by every sample,
    and empty outputs for no sample."""
    import casadi as ca
    import numpy as np

    from excavator_payload.model.codegen import ColumnMap, column_map

    x = ca.SX.sym("x", 3)
    p = ca.SX.sym("p", 2)
    y = ca.vertcat(ca.sin(x[0]) * p[0], x[1] * x[2] + p[1], ca.exp(x[2]))
    f = ca.Function("f", [x, p], [y, ca.jacobian(y, x), ca.sum1(y)])
    assert f.sparsity_out(1).nnz() < 9  # structural zeros
    rng = np.random.default_rng(1)
    n = 37
    xs, ps = rng.normal(size=(3, n)), rng.normal(size=2)
    reference = [np.asarray(o) for o in f.map(n, "serial")(xs, np.repeat(ps[:, None], n, 1))]
    got = ColumnMap(f, n)(xs, ps)
    assert [g.shape for g in got] == [r.shape for r in reference] == [(3, n), (3, 3 * n), (1, n)]
    for g, r in zip(got, reference):
        assert np.array_equal(g, r)
    # cached per (function, n): the second call reuses the buffers and overwrites them
    again = column_map(f, n)
    assert column_map(f, n) is again
    first = again(xs, ps)[0]
    second = again(2 * xs, ps)[0]
    assert not np.array_equal(first, second) and np.array_equal(first, reference[0])
    assert [o.shape for o in ColumnMap(f, 0)(np.zeros((3, 0)), ps)] == [(3, 0), (3, 0), (1, 0)]


def test_buffered_call_equals_the_function_call_and_keeps_its_stats():
    """A solver called through :class:`BufferedCall` returns CasADi's own numbers (bit for bit)
    and its statistics; an input not given is zero, a scalar fills its vector."""
    import casadi as ca
    import numpy as np

    from excavator_payload.model.codegen import BufferedCall

    x, p = ca.SX.sym("x", 2), ca.SX.sym("p")
    solver = ca.nlpsol("s", "sqpmethod", {"x": x, "p": p, "f": (x[0] - p) ** 2 + (x[1] - 1) ** 4,
                                          "g": x[0] + x[1]},
                       {"print_time": False, "print_header": False, "print_iteration": False,
                        "print_status": False, "qpsol": "qrqp",
                        "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False}})
    call = BufferedCall(solver)
    got = call(x0=np.array([0.3, 0.2]), p=2.0, lbg=-1.0, ubg=1.5, lbx=-np.inf, ubx=np.inf)
    want = solver(x0=[0.3, 0.2], p=2.0, lbg=-1.0, ubg=1.5, lbx=-np.inf, ubx=np.inf)
    for name in ("x", "f", "g", "lam_g", "lam_x"):
        assert np.array_equal(got[name], np.asarray(want[name]).ravel())
    assert call.stats()["return_status"] == solver.stats()["return_status"]
    assert call.stats()["success"] is True
