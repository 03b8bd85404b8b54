"""The code's shape: modules talk through public names, and the code map lists every module.

`lint-imports` (``make lint``) checks which module may import which; these tests check what
an import graph cannot see. A checker walks ``src/sonarmap`` with :mod:`ast` and reports

- ``private-module``: ``import pkg._mod``, ``from pkg._mod import x`` or ``pkg._mod.x``
  (through an imported package) from outside ``pkg`` (a package's private modules are for
  that package and its subpackages);
- ``private-name``: ``from mod import _name``, another module's private name;
- ``module-attribute``: ``mod._name`` on an imported module, ``_name`` not a submodule;
- ``foreign-field``: ``obj._field`` (read or written, or by ``getattr``/``setattr``/
  ``hasattr`` with a literal name) where ``obj`` is not ``self``, ``cls``, ``super()`` or
  ``type(self)``: another object's private state.

Dunder names are public, as are the ``_replace``/``_asdict``/``_fields``/``_make``/
``_field_defaults`` methods of NamedTuples. The checker reads ``src/sonarmap`` and, as
clients of the library that users copy from, ``benchmarks``; not the tests, which may reach
inside what they test.
"""

from __future__ import annotations

import ast
import re
import textwrap
import tomllib
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
CODE_MAP = ROOT / "docs" / "reference" / "code-map.md"

NAMEDTUPLE_API = frozenset({"_replace", "_asdict", "_fields", "_make", "_field_defaults"})
OWN = frozenset({"self", "cls"})
NAME_BUILTINS = frozenset({"getattr", "setattr", "hasattr", "delattr"})

# (module, text) pairs found by the checker and kept on purpose, each with why. A stale
# entry fails the test, so the list only shrinks.
ALLOWED: frozenset[tuple[str, str]] = frozenset()
# The same for the benchmarks.
ALLOWED_BENCHMARKS: frozenset[tuple[str, str]] = frozenset(
    {
        # Times the numba insertion kernel alone, below the public ``accumulate``'s
        # argument checks and dispatch: the kernel is what it measures.
        ("benchmarks.mrpt.profile", "from sonarmap._raster_kernel import LANES"),
        (
            "benchmarks.mrpt.profile",
            "from sonarmap._raster_kernel import accumulate_kernel as _kernel",
        ),
    }
)


class Module(NamedTuple):
    """One parsed module: its syntax tree and whether it is a package's ``__init__``."""

    tree: ast.Module
    is_package: bool


class Finding(NamedTuple):
    """One use of a private name across a boundary: where, which kind, and the code."""

    module: str
    line: int
    kind: str
    text: str


def is_private(name: str) -> bool:
    """A leading underscore, dunders excepted."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def load_package(src: Path, package: str) -> dict[str, Module]:
    """Every module of ``package`` under ``src``, by dotted name."""
    modules: dict[str, Module] = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        name = ".".join(parts[:-1] if is_package else parts)
        modules[name] = Module(ast.parse(path.read_text(encoding="utf-8"), str(path)), is_package)
    return modules


def _outside(target: str, package: str) -> bool:
    """Whether ``target`` passes through a private module of a package that does not hold
    ``package`` (the importer's package)."""
    parts = target.split(".")
    for i in range(1, len(parts)):
        if is_private(parts[i]):
            owner = ".".join(parts[:i])
            return package != owner and not package.startswith(owner + ".")
    return False


def _base(node: ast.ImportFrom, package: str) -> str:
    if not node.level:
        return node.module or ""
    parts = package.split(".")
    parts = parts[: len(parts) - node.level + 1]
    return ".".join([*parts, node.module] if node.module else parts)


def _is_own(node: ast.expr) -> bool:
    if isinstance(node, ast.Name):
        return node.id in OWN
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in {"super", "type"}
        and all(_is_own(a) for a in node.args)
    )


def _module_of(node: ast.expr, bound: dict[str, str], modules: dict[str, Module]) -> str | None:
    """The module that ``node`` (a bound name, or attributes on one) refers to, if any."""
    if isinstance(node, ast.Name):
        return bound.get(node.id)
    if isinstance(node, ast.Attribute):
        owner = _module_of(node.value, bound, modules)
        if owner is not None and f"{owner}.{node.attr}" in modules:
            return f"{owner}.{node.attr}"
    return None


def check_module(name: str, modules: dict[str, Module]) -> list[Finding]:
    """The private names that module ``name`` uses across a boundary."""
    tree, is_package = modules[name]
    package = name if is_package else name.rpartition(".")[0]
    findings: list[Finding] = []
    bound: dict[str, str] = {}  # local name -> the module it is bound to

    def flag(node: ast.stmt | ast.expr, kind: str) -> None:
        findings.append(Finding(name, node.lineno, kind, ast.unparse(node)))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if _outside(alias.name, package):
                    flag(node, "private-module")
                local = alias.asname or alias.name.split(".")[0]
                bound[local] = alias.name if alias.asname else local
        elif isinstance(node, ast.ImportFrom):
            base = _base(node, package)
            if _outside(base, package):
                flag(node, "private-module")
            for alias in node.names:
                full = f"{base}.{alias.name}"
                if full in modules:
                    if _outside(full, package):
                        flag(node, "private-module")
                    bound[alias.asname or alias.name] = full
                elif is_private(alias.name):
                    flag(node, "private-name")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and is_private(node.attr):
            owner = node.value
            target = _module_of(owner, bound, modules)
            if target is not None:
                if f"{target}.{node.attr}" not in modules:
                    flag(node, "module-attribute")
                elif _outside(f"{target}.{node.attr}", package):
                    flag(node, "private-module")
            elif not _is_own(owner) and node.attr not in NAMEDTUPLE_API:
                flag(node, "foreign-field")
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in NAME_BUILTINS
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant)
            and isinstance(node.args[1].value, str)
            and is_private(node.args[1].value)
            and not _is_own(node.args[0])
        ):
            flag(node, "foreign-field")
    return findings


def check_modules(modules: dict[str, Module]) -> list[Finding]:
    """Every private name used across a boundary in ``modules``, by module and line."""
    return sorted(f for name in sorted(modules) for f in check_module(name, modules))


def _synthetic(sources: dict[str, str]) -> dict[str, Module]:
    """Modules from source text; a name ending in ``.__init__`` is a package."""
    modules: dict[str, Module] = {}
    for name, text in sources.items():
        tree = ast.parse(textwrap.dedent(text))
        if name.endswith(".__init__"):
            modules[name.removesuffix(".__init__")] = Module(tree, True)
        else:
            modules[name] = Module(tree, False)
    return modules


# A tiny package: pkg.sub holds a private module _impl with a numba kernel and a private
# helper (a kernel is as private as any other function); pkg.user sits outside pkg.sub.
_PACKAGE = {
    "pkg.__init__": "",
    "pkg.sub.__init__": "from ._impl import Public\n",
    "pkg.sub._impl": """
        import numba

        class Public:
            pass

        def _helper() -> None:
            pass

        @numba.njit(cache=True)
        def _kernel(x):
            return x
    """,
    "pkg.sub.tool": "",
}


@pytest.mark.parametrize(
    ("code", "kind"),
    [
        ("from pkg.sub._impl import Public\n", "private-module"),
        ("import pkg.sub._impl\n", "private-module"),
        ("from pkg.sub import _impl\n", "private-module"),
        ("from pkg import sub\nsub._impl.Public\n", "private-module"),
        ("import pkg.sub\npkg.sub._impl.Public\n", "private-module"),
        ("import pkg.sub.tool\npkg.sub.tool._name()\n", "module-attribute"),
        ("from pkg.sub.tool import _name\n", "private-name"),
        ("from pkg.sub import tool\ntool._name()\n", "module-attribute"),
        ("import pkg.sub.tool as t\nt._name = 1\n", "module-attribute"),
        ("def f(other):\n    return other._state\n", "foreign-field"),
        ("class A:\n    def f(self):\n        return self.part._state\n", "foreign-field"),
        ("def f(other):\n    other._state = 0\n", "foreign-field"),
        ("def f(other):\n    return getattr(other, '_state', None)\n", "foreign-field"),
    ],
)
def test_checker_flags_bad_source(code: str, kind: str) -> None:
    modules = _synthetic({**_PACKAGE, "pkg.user": code})
    found = check_module("pkg.user", modules)
    assert [f.kind for f in found] == [kind], found


@pytest.mark.parametrize(
    "code",
    [
        "from pkg.sub import Public\n",
        "class A:\n    def f(self):\n        self._x = 1\n        return self._x\n",
        "class A:\n    @classmethod\n    def f(cls):\n        return cls._x\n",
        "class A(dict):\n    def f(self):\n        return super()._x + type(self)._y\n",
        "def f(p):\n    return p._replace(x=1), p._asdict(), p.__class__\n",
        "def f(self):\n    return getattr(self, '_router', None)\n",
    ],
)
def test_checker_passes_good_source(code: str) -> None:
    modules = _synthetic({**_PACKAGE, "pkg.user": code})
    assert check_module("pkg.user", modules) == []


@pytest.mark.parametrize(
    "code",
    [
        # Inside the package that owns the private module: its public names.
        "from ._impl import Public\n",
        "from pkg.sub._impl import Public\n",
        "from . import _impl\n_impl.Public()\n",
        "from pkg import sub\nsub._impl.Public()\n",
    ],
)
def test_checker_lets_a_package_use_its_private_modules(code: str) -> None:
    modules = _synthetic({**_PACKAGE, "pkg.sub.tool": code})
    assert check_module("pkg.sub.tool", modules) == []


@pytest.mark.parametrize(
    ("code", "kind"),
    [
        ("from ._impl import _helper\n", "private-name"),
        ("from ._impl import _kernel\n", "private-name"),
        ("from . import _impl\n_impl._kernel(1)\n", "module-attribute"),
    ],
)
def test_checker_flags_a_private_function_even_inside_the_package(code: str, kind: str) -> None:
    modules = _synthetic({**_PACKAGE, "pkg.sub.tool": code})
    assert [f.kind for f in check_module("pkg.sub.tool", modules)] == [kind]


def test_src_uses_no_private_name_across_a_boundary() -> None:
    modules = load_package(SRC, "sonarmap")
    assert len(modules) > 100, "src/sonarmap not found where expected"
    found = {(f.module, f.text): f for f in check_modules(modules)}
    unexpected = [
        f"{f.module}:{f.line}: {f.kind}: {f.text}" for k, f in found.items() if k not in ALLOWED
    ]
    stale = sorted(ALLOWED - found.keys())
    assert not unexpected, "\n".join(unexpected)
    assert not stale, f"allow-list entries no longer found: {stale}"


def test_benchmarks_use_only_public_names() -> None:
    library = load_package(SRC, "sonarmap")
    benchmarks = load_package(ROOT, "benchmarks")
    assert len(benchmarks) > 20, "benchmarks/ not found where expected"
    found = {
        (f.module, f.text): f
        for f in check_modules(library | benchmarks)
        if f.module.startswith("benchmarks")
    }
    unexpected = [
        f"{f.module}:{f.line}: {f.kind}: {f.text}"
        for k, f in found.items()
        if k not in ALLOWED_BENCHMARKS
    ]
    stale = sorted(ALLOWED_BENCHMARKS - found.keys())
    assert not unexpected, "\n".join(unexpected)
    assert not stale, f"allow-list entries no longer found: {stale}"


def test_code_map_lists_every_module() -> None:
    modules = load_package(SRC, "sonarmap")
    text = CODE_MAP.read_text(encoding="utf-8")
    # A module counts as listed only in its own row of a table, not when prose names it.
    listed = set(re.findall(r"^\| `(sonarmap(?:\.\w+)*)` \|", text, flags=re.MULTILINE))
    missing = sorted(set(modules) - listed)
    unknown = sorted(listed - set(modules))
    assert not missing, f"modules missing from {CODE_MAP.name}: {missing}"
    assert not unknown, f"{CODE_MAP.name} names modules that do not exist: {unknown}"


def test_code_map_shows_the_contract_layers() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = config["tool"]["importlinter"]["contracts"]
    (layers,) = [c["layers"] for c in contracts if c["type"] == "layers"]
    text = CODE_MAP.read_text(encoding="utf-8")
    shown = re.findall(r"^\d+\. `([^`]+)`:", text, flags=re.MULTILINE)
    assert shown == layers
