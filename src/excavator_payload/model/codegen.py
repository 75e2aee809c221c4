"""C code generation of symbolic-model functions, with one on-disk cache for every user.

The NMPC's interval model, the Kalman filter steps (and, later, the ECU export) are CasADi
functions of the symbolic arm model. Compiled to C they run 10–15× faster than CasADi's
virtual machine. :func:`native` compiles once per machine and user, keyed by a hash of the
generated code, stores the library's SHA-256 beside it and loads it with :func:`casadi.external`
only when it still matches (a truncated or altered library is rebuilt, never loaded); without a C
compiler (or with ``EXCAVATOR_PAYLOAD_NATIVE=0``), or if compiling fails, it returns the
function itself: the same numbers, slower.

Cache folder: ``$EXCAVATOR_PAYLOAD_CACHE``, else ``$XDG_CACHE_HOME/excavator-payload``, else
``~/.cache/excavator-payload``; compiled libraries live in its ``native/`` subfolder.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import casadi as ca
import numpy as np

log = logging.getLogger(__name__)

#: Set to ``0`` to never compile (always CasADi's virtual machine).
NATIVE_ENV = "EXCAVATOR_PAYLOAD_NATIVE"
#: -O1 compiles the 0.8 MB NMPC Jacobian about 2× faster than -O2 at the same run time.
FLAGS = ("-O1", "-fPIC", "-shared")
#: Memory slots per generated solver function: CasADi's generated code keeps one static memory
#: per live caller and has one slot unless told (a second live controller in a process got slot
#: -1 and crashed the process); :mod:`.compiled_sqp` falls back to CasADi's solver beyond it.
SOLVER_SLOTS = 256
#: For the generated SQP solvers' loops (``qrqp``'s sparse QR): -O2 runs them ~10 % faster than
#: -O1, the same numbers (no fast-math); their straight-line models keep :data:`FLAGS`.
LOOP_FLAGS = ("-O2", "-fPIC", f"-DCASADI_MAX_NUM_THREADS={SOLVER_SLOTS}")


def compiler() -> str | None:
    """The C compiler to use (``$CC``, gcc or cc), or None if there is none or it is disabled."""
    if os.environ.get(NATIVE_ENV, "1") == "0":
        return None
    return shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")


def cache_folder() -> Path:
    """Where compiled libraries are kept (see the module docstring)."""
    root = os.environ.get("EXCAVATOR_PAYLOAD_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "excavator-payload")
    return Path(root) / "native"


def compiled_library(functions: list[ca.Function], name: str, edit=None,
                     linked: list[ca.Function] = ()) -> Path:
    """C code of ``functions`` compiled to a shared library, cached by content hash.

    The library is built in a temporary folder and renamed into place, so concurrent
    processes never load half a file. Raises ``OSError`` / ``subprocess.SubprocessError`` if
    there is no compiler or it fails.

    Parameters
    ----------
    functions : list of casadi.Function
        The functions to compile into one library.
    name : str
        The library's base name (the C file's and the exported module's).
    edit : callable, optional
        ``edit(source) -> source``: changes the generated C before it is hashed and compiled
        (:mod:`excavator_payload.model.compiled_sqp` adds the solver's return status).
    linked : list of casadi.Function, optional
        Functions generated into a second C file of the same library: those that ``functions``
        call as :func:`casadi.external` (CasADi will not generate a function under the name
        of an external it calls).

    Returns
    -------
    pathlib.Path
        The shared library in :func:`cache_folder`.
    """
    cc = compiler()
    if cc is None:
        raise OSError("no C compiler (or compilation disabled by EXCAVATOR_PAYLOAD_NATIVE=0)")
    generator = ca.CodeGenerator(f"{name}.c", {"with_header": False})
    for f in functions:
        generator.add(f)
    source = generator.dump()
    if edit is not None:
        source = edit(source)
    sources = {f"{name}.c": source}
    if linked:
        companion = ca.CodeGenerator(f"{name}_linked.c", {"with_header": False})
        for f in linked:
            companion.add(f)
        sources[f"{name}_linked.c"] = companion.dump()
    flags = " ".join(FLAGS) + (" " + " ".join(LOOP_FLAGS) if linked else "")
    digest = hashlib.sha256(("\n".join(sources.values()) + flags + ca.__version__).encode()).hexdigest()[:20]
    folder = cache_folder()
    library = folder / f"{name}_{digest}.so"
    if verified(library):
        return library
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        c_files = []
        for file_name, text in sources.items():
            c_files.append(Path(tmp) / file_name)
            c_files[-1].write_text(text, encoding="utf-8")
        built = Path(tmp) / library.name
        run = dict(check=True, capture_output=True, text=True, timeout=600)
        if linked:  # the solver at LOOP_FLAGS, the model it calls at FLAGS, one library
            objects = [c.with_suffix(".o") for c in c_files]
            subprocess.run([cc, *LOOP_FLAGS, "-c", str(c_files[0]), "-o", str(objects[0])], **run)
            subprocess.run([cc, *[f for f in FLAGS if f != "-shared"], "-c", str(c_files[1]), "-o",
                            str(objects[1])], **run)
            subprocess.run([cc, "-shared", *map(str, objects), "-o", str(built), "-lm"], **run)
        else:
            subprocess.run([cc, *FLAGS, *map(str, c_files), "-o", str(built), "-lm"], **run)
        checksum = Path(tmp) / (library.name + ".sha256")
        checksum.write_text(file_sha256(built), encoding="utf-8")
        # The library first, its checksum second: a library without a matching checksum next
        # to it is never loaded (a reader in between just builds it again).
        os.replace(built, library)
        os.replace(checksum, _checksum_path(library))
    return library


def file_sha256(path: Path) -> str:
    """SHA-256 (hex) of a file's bytes.

    Parameters
    ----------
    path : pathlib.Path
        The file to hash.
    """
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _checksum_path(library: Path) -> Path:
    return library.with_name(library.name + ".sha256")


def verified(library: Path) -> bool:
    """Whether ``library`` exists and matches the SHA-256 stored beside it when it was built.

    A truncated or altered shared library must never be loaded: mapping it can kill the process
    with SIGBUS, which no ``except`` catches. Anything that does not match is rebuilt.

    Parameters
    ----------
    library : pathlib.Path
        The shared library; its checksum is the file of the same name plus ``.sha256``.
    """
    try:
        if not library.is_file():
            return False
        return _checksum_path(library).read_text(encoding="utf-8").strip() == file_sha256(library)
    except OSError:
        return False


def native(function: ca.Function, *companions: ca.Function) -> ca.Function:
    """``function`` as compiled C, or ``function`` itself where that is not possible.

    ``companions`` are compiled into the same library, e.g. ``function.jacobian()`` so that
    CasADi's ``external`` finds compiled derivatives too.

    Parameters
    ----------
    function : casadi.Function
        The function to compile; its name names the library.
    *companions : casadi.Function
        Further functions compiled into the same library.
    """
    if compiler() is None:
        return function
    name = function.name()
    try:
        library = compiled_library([function, *companions], name)
        return ca.external(name, str(library))
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
        log.warning("compiling %s failed, using CasADi's virtual machine: %s", name, exc)
        return function


class ColumnMap:
    """A one-sample CasADi function evaluated on ``n`` samples at once, numpy in and out.

    ``function.map(n, "serial")`` evaluates every sample in one call, but CasADi hands each
    output back as a ``DM``, and converting a ``DM`` to numpy goes through a Python list of its
    elements: for the calibration's Jacobians (12 × 77 numbers a sample, thousands of samples)
    that conversion cost more than the evaluation (11.5 of 28.7 s of a three-swing
    calibration). Here the inputs and outputs are numpy arrays the mapped function reads and
    writes in place through CasADi's buffer interface; sparse outputs are scattered into dense
    arrays by their sparsity pattern. The numbers are CasADi's own, bit for bit.

    Parameters
    ----------
    function : casadi.Function
        One sample: every input and output a column vector or a matrix.
    n : int
        Number of samples.
    """

    def __init__(self, function: ca.Function, n: int):
        self.n = int(n)
        self.function = function  # held, so that no other function takes its id in the cache
        # kept alive: the buffers point into it (CasADi has no map over 0 samples: one sample's
        # map then, its outputs cut to 0 columns)
        self._mapped = function.map(max(self.n, 1), "serial")
        self._inputs = [np.zeros(self._mapped.nnz_in(i)) for i in range(self._mapped.n_in())]
        if any(self._mapped.nnz_in(i) != self._mapped.size1_in(i) * self._mapped.size2_in(i)
               for i in range(self._mapped.n_in())):
            raise ValueError(f"{function.name()}: ColumnMap needs dense inputs")
        self._outputs = [np.zeros(self._mapped.nnz_out(i)) for i in range(self._mapped.n_out())]
        self._patterns = []
        for i in range(self._mapped.n_out()):
            sp = self._mapped.sparsity_out(i)
            rows, cols = sp.get_triplet()
            self._patterns.append((sp.size1(), sp.size2(), np.asarray(rows, int), np.asarray(cols, int)))
        self._buffer, self._trigger = self._mapped.buffer()
        for i, array in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self._outputs):
            self._buffer.set_res(i, memoryview(array))

    def __call__(self, *inputs) -> list:
        """Outputs for ``inputs``, each ``(rows, n)`` like the mapped function's ``DM``; an input is
        a ``(rows, n)`` array, or a ``(rows,)`` vector shared by every sample."""
        if self.n == 0:
            f = self.function
            return [np.zeros((f.size1_out(i), 0)) for i in range(f.n_out())]
        for i, (buffer, value) in enumerate(zip(self._inputs, inputs)):
            value = np.asarray(value, dtype=float)
            rows = self._mapped.size1_in(i)
            if value.ndim == 1:
                value = np.broadcast_to(value[:, None], (rows, self.n))
            buffer[:] = value.reshape(rows, -1).ravel(order="F")
        self._trigger()
        out = []
        for values, (rows, cols, r, c) in zip(self._outputs, self._patterns):
            if len(values) == rows * cols:  # dense: column-major as it is
                out.append(values.reshape(cols, rows).T.copy())
            else:
                dense = np.zeros((rows, cols))
                dense[r, c] = values
                out.append(dense)
        return out


def column_map(function: ca.Function, n: int) -> ColumnMap:
    """A :class:`ColumnMap` of ``function`` on ``n`` samples. The last few are kept per thread
    (calibration evaluates the same samples once per iteration; a map's buffers are its state,
    so threads never share one).

    Parameters
    ----------
    function : casadi.Function
        The function to map over samples.
    n : int
        Number of samples (columns) the map evaluates at once.
    """
    cache = getattr(_LOCAL, "maps", None)
    if cache is None:
        cache = _LOCAL.maps = {}
    key = (id(function), int(n))
    cached = cache.pop(key, None)
    if cached is None:
        cached = ColumnMap(function, n)
    cache[key] = cached
    while len(cache) > 8:
        cache.pop(next(iter(cache)))
    return cached


_LOCAL = threading.local()


class BufferedCall:
    """A CasADi function called on numpy vectors through its buffer interface.

    Calling a ``casadi.Function`` from Python converts every argument to a ``DM`` and every
    result back: for the NMPC's solvers (eight vector arguments, six results, tens of thousands
    of calls per dataset) that conversion cost a third of a solve. Here the arguments are copied
    into numpy arrays the function reads in place and the results come out of arrays it writes;
    the numbers are CasADi's own, bit for bit. Not thread-safe: one per controller.

    Parameters
    ----------
    function : casadi.Function
        Every input and output dense (e.g. an ``nlpsol`` solver).
    """

    def __init__(self, function: ca.Function):
        self.function = function  # held: the buffer points into its memory
        self._names_in = function.name_in()
        self._names_out = function.name_out()
        self._inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self._outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        self._buffer, self._trigger = function.buffer()
        for i, array in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self._outputs):
            self._buffer.set_res(i, memoryview(array))

    def __call__(self, **inputs) -> dict[str, np.ndarray]:
        """The outputs by name (copies) for ``inputs`` by name; an input not given is zero,
        a scalar fills its vector.

        Parameters
        ----------
        **inputs : numpy.ndarray or float
            Values of the function's inputs, by name.
        """
        for name, array in zip(self._names_in, self._inputs):
            array[:] = inputs.get(name, 0.0)
        self._trigger()
        return {name: array.copy() for name, array in zip(self._names_out, self._outputs)}

    def stats(self) -> dict:
        """The statistics of the last call (an ``nlpsol``'s ``return_status``, ``success``, …)."""
        return self._buffer.stats()
