"""Docstring conformance (in the spirit of python-control's docstring test, numpydoc style).

Walks every module of ``excavator_payload`` and checks that

* every module, every public function and class defined in it, and every public method
  defined on such a class has a non-empty docstring;
* wherever a docstring has a numpydoc ``Parameters`` section, the names documented there
  are exactly the parameters of the signature (``__init__``'s for a class), not counting
  ``self``/``cls``.  ``*args``/``**kwargs`` need not be documented, and when the signature
  takes ``**kwargs`` extra documented names (keyword options) are allowed.

Each check reports every violation at once, one line each.
"""

import dataclasses
import importlib
import inspect
import pkgutil
import re
import typing

import pytest

import excavator_payload

PACKAGE = excavator_payload

_DASHES = re.compile(r"^\s*-{3,}\s*$")


# ---------------------------------------------------------------- collecting the objects

def _modules():
    """Every module of the package (the package itself first), imported."""
    mods = [PACKAGE]
    for info in pkgutil.walk_packages(PACKAGE.__path__, prefix=PACKAGE.__name__ + "."):
        mods.append(importlib.import_module(info.name))
    return mods


def _public_members(module):
    """``(qualified name, object)`` of the public functions and classes defined in ``module``,
    and of the public methods defined on those classes."""
    out = []
    for name, obj in sorted(vars(module).items()):
        if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
            continue
        if inspect.isfunction(obj):
            out.append((f"{module.__name__}.{name}", obj))
        elif inspect.isclass(obj):
            out.append((f"{module.__name__}.{name}", obj))
            for mname, attr in sorted(vars(obj).items()):
                if mname.startswith("_"):
                    continue
                if isinstance(attr, (staticmethod, classmethod)):
                    attr = attr.__func__
                if inspect.isfunction(attr):
                    out.append((f"{module.__name__}.{name}.{mname}", (obj, attr)))
    return out


def _own_doc(obj):
    """The docstring ``obj`` really has, or ``""``.

    Methods may inherit the docstring of the method they override (numpydoc's rule);
    a class must have its own (not a base class's, and not the signature that
    ``dataclasses`` or ``NamedTuple`` write into ``__doc__`` when there is none).
    """
    if isinstance(obj, tuple):  # (class, method)
        klass, func = obj
        doc = func.__doc__
        if not doc:
            for base in klass.__mro__[1:]:
                inherited = vars(base).get(func.__name__)
                if isinstance(inherited, (staticmethod, classmethod)):
                    inherited = inherited.__func__
                if inherited is not None and getattr(inherited, "__doc__", None):
                    doc = inherited.__doc__
                    break
        return inspect.cleandoc(doc or "")
    if inspect.isclass(obj):
        doc = vars(obj).get("__doc__") or ""
        if dataclasses.is_dataclass(obj):
            try:
                generated = obj.__name__ + str(inspect.signature(obj)).replace(" -> None", "")
            except (TypeError, ValueError):
                generated = None
            if doc == generated:
                doc = ""
        fields = getattr(obj, "_fields", None)
        if issubclass(obj, tuple) and fields is not None:
            arg_list = repr(tuple(fields)).replace("'", "")[1:-1]  # as collections.namedtuple
            if doc == f"{obj.__name__}({arg_list})":
                doc = ""
        return inspect.cleandoc(doc)
    return inspect.cleandoc(getattr(obj, "__doc__", None) or "")


# ---------------------------------------------------------------- the checker

def documented_parameters(doc):
    """Names documented in the numpydoc ``Parameters`` section of ``doc``, or ``None``
    when it has no such section."""
    lines = doc.splitlines()
    start = None
    for i in range(len(lines) - 1):
        if lines[i].strip() == "Parameters" and _DASHES.match(lines[i + 1]):
            start = i + 2
            break
    if start is None:
        return None
    names = []
    for i in range(start, len(lines)):
        line = lines[i]
        is_header = (line[:1].isupper() and i + 1 < len(lines)
                     and _DASHES.match(lines[i + 1]))
        if is_header:
            break
        if not line.strip() or line[0].isspace():
            continue
        head = line.split(" :", 1)[0]
        names.extend(part.strip().lstrip("*") for part in head.split(",") if part.strip())
    return names


def signature_of(obj):
    """The signature a docstring documents: the function's, or a class's ``__init__``."""
    if isinstance(obj, tuple):
        obj = obj[1]
    if inspect.isclass(obj):
        return inspect.signature(obj.__init__)
    return inspect.signature(obj)


def parameter_mismatch(obj, doc=None):
    """``(missing, extra)`` between ``obj``'s documented parameters and its signature,
    or ``None`` when its docstring has no ``Parameters`` section."""
    doc = _own_doc(obj) if doc is None else inspect.cleandoc(doc)
    documented = documented_parameters(doc)
    if documented is None:
        return None
    params = [p for p in signature_of(obj).parameters.values() if p.name not in ("self", "cls")]
    required = [p.name for p in params
                if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    accepted = {p.name for p in params}
    takes_options = any(p.kind is p.VAR_KEYWORD for p in params)
    missing = [n for n in required if n not in documented]
    extra = [] if takes_options else [n for n in documented if n not in accepted]
    return missing, extra


def docstring_violations(members):
    """Names of the objects among ``members`` (``(name, object)``) that lack a docstring."""
    return [name for name, obj in members if not _own_doc(obj).strip()]


def parameter_violations(members):
    """One line per object among ``members`` whose Parameters section disagrees with
    its signature."""
    out = []
    for name, obj in members:
        result = parameter_mismatch(obj)
        if result is None:
            continue
        missing, extra = result
        if missing or extra:
            out.append(f"{name}: missing {missing} extra {extra}")
    return out


def takes_parameters(obj) -> bool:
    """Whether ``obj`` takes named parameters a reader must be told about: a function's or
    method's besides ``self``/``cls``/``*args``/``**kwargs``; a class's only when it defines
    its own ``__init__`` (a dataclass's generated one included)."""
    if inspect.isclass(obj):
        if "__init__" not in vars(obj):
            return False
        func = obj.__init__
    else:
        func = obj[1] if isinstance(obj, tuple) else obj
    try:
        params = inspect.signature(func).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name not in ("self", "cls") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
               for p in params)


def undocumented_parameters(members):
    """Names of the objects among ``members`` that take parameters but document none (no
    numpydoc ``Parameters`` section, own or inherited from the method they override)."""
    return [name for name, obj in members
            if takes_parameters(obj) and documented_parameters(_own_doc(obj)) is None]


# ---------------------------------------------------------------- the tests

MODULES = _modules()
MEMBERS = [m for mod in MODULES for m in _public_members(mod)]


def test_walk_finds_the_package():
    names = {m.__name__ for m in MODULES}
    assert "excavator_payload.estimators.base" in names
    assert "excavator_payload.simulation.machine_sim" in names
    assert len(MEMBERS) > 100


def test_every_module_has_a_docstring():
    bad = [m.__name__ for m in MODULES if not (m.__doc__ or "").strip()]
    assert not bad, "modules without a docstring:\n" + "\n".join(bad)


def test_every_public_function_class_and_method_has_a_docstring():
    bad = docstring_violations(MEMBERS)
    assert not bad, "public objects without a docstring:\n" + "\n".join(bad)


def test_every_public_callable_documents_its_parameters():
    bad = undocumented_parameters(MEMBERS)
    assert not bad, ("public callables that take parameters but have no Parameters section:\n"
                     + "\n".join(bad))


def test_parameters_sections_match_signatures():
    bad = parameter_violations(MEMBERS)
    assert not bad, "Parameters sections that disagree with the signature:\n" + "\n".join(bad)


# ---------------------------------------------------------------- the checker can fail

def _bad_dummy(alpha, beta, gamma=1.0):
    """A deliberately wrong docstring.

    Parameters
    ----------
    alpha : float
        Documented and real.
    delta : int
        Documented but not a parameter.
    gamma : float
        Wrapped description whose continuation
    line starts at column 0.

    Returns
    -------
    beta : float
        Not a parameter section, must not count.
    """


def _good_dummy(alpha, beta, *args, **kwargs):
    """A conforming docstring.

    Parameters
    ----------
    alpha, beta : float
        Two names on one line.
    *args
        Positional extras.
    option : bool
        A keyword option passed through ``**kwargs``.

    Returns
    -------
    None
    """


class _BadClass:
    """A class whose Parameters section documents the wrong names.

    Parameters
    ----------
    x : float
        Not an argument of ``__init__``.
    """

    def __init__(self, y):
        self.y = y

    def method(self):
        pass


@dataclasses.dataclass
class _UndocumentedData:
    x: float


class _UndocumentedTuple(typing.NamedTuple):
    x: float


def test_checker_flags_a_bad_dummy():
    missing, extra = parameter_mismatch(_bad_dummy)
    assert missing == ["beta"]
    assert extra == ["delta", "line starts at column 0."]
    assert parameter_violations([("dummy", _bad_dummy)]) == [
        "dummy: missing ['beta'] extra ['delta', 'line starts at column 0.']"]
    assert parameter_mismatch(_BadClass) == (["y"], ["x"])
    assert parameter_mismatch(_good_dummy) == ([], [])
    assert parameter_mismatch(lambda x: x, doc="No sections at all.") is None
    members = [("cls", _BadClass), ("cls.method", (_BadClass, _BadClass.method)),
               ("good", _good_dummy), ("data", _UndocumentedData), ("tuple", _UndocumentedTuple)]
    # the signature dataclasses / NamedTuple put into __doc__ is not a docstring
    assert docstring_violations(members) == ["cls.method", "data", "tuple"]


def test_checker_flags_undocumented_parameters():
    def takes(alpha):
        """Says nothing of alpha."""

    def takes_none(*args, **kwargs):
        """Nothing named to document."""

    members = [("takes", takes), ("none", takes_none), ("good", _good_dummy), ("cls", _BadClass),
               ("cls.method", (_BadClass, _BadClass.method)), ("data", _UndocumentedData)]
    assert undocumented_parameters(members) == ["takes", "data"]


@pytest.mark.parametrize("doc", ["", "   \n  "])
def test_checker_flags_an_empty_docstring(doc):
    def dummy():
        pass
    dummy.__doc__ = doc
    assert docstring_violations([("dummy", dummy)]) == ["dummy"]
