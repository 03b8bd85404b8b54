"""The benchmarks index (``docs/reference/benchmarks.md``) lists every script, and only scripts.

A script is a module under ``benchmarks/`` (subpackages included, ``__init__`` left out)
with a top-level ``if __name__ == "__main__":`` block, run as ``python -m benchmarks.NAME``.
Helpers without that block are not scripts and need no row. The index gives each script a
table row whose first cell starts with its command; every dotted ``benchmarks.NAME`` the
page mentions, anywhere, must be such a script.
"""

from __future__ import annotations

import ast
import re
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
INDEX = ROOT / "docs" / "reference" / "benchmarks.md"

# A table row whose first cell starts with a script's command.
ROW = re.compile(r"^\|\s*`python -m (benchmarks(?:\.[a-z_][a-z0-9_]*)+)", re.MULTILINE)
# A dotted module name, not part of a file name (``2026-11-22-benchmarks.md``);
# upper-case placeholders such as ``benchmarks.NAME`` do not match.
NAMED = re.compile(r"(?<![\w/.-])benchmarks(?:\.[a-z_][a-z0-9_]*)+")


def _runs_as_main(path: Path) -> bool:
    """Whether the module at ``path`` has a top-level ``if __name__ == "__main__":`` block."""
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if not isinstance(node, ast.If):
            continue
        test = node.test
        if (
            isinstance(test, ast.Compare)
            and isinstance(test.left, ast.Name)
            and test.left.id == "__name__"
            and len(test.comparators) == 1
            and isinstance(test.comparators[0], ast.Constant)
            and test.comparators[0].value == "__main__"
        ):
            return True
    return False


def scripts(package: Path) -> set[str]:
    """Dotted names of the scripts in the package directory ``package``.

    Parameters
    ----------
    package : Path
        The ``benchmarks`` directory; its name is the names' first part.

    Returns
    -------
    set of str
        ``benchmarks.NAME`` (or ``benchmarks.SUB.NAME``) for every module with a
        top-level ``__main__`` block, ``__init__`` modules left out.
    """
    found: set[str] = set()
    for path in package.rglob("*.py"):
        if path.name == "__init__.py" or not _runs_as_main(path):
            continue
        found.add(".".join(path.relative_to(package.parent).with_suffix("").parts))
    return found


def index_problems(page: str, package: Path) -> list[str]:
    """What is wrong with the index ``page`` against the scripts in ``package``.

    Parameters
    ----------
    page : str
        The index's Markdown.
    package : Path
        The ``benchmarks`` directory.

    Returns
    -------
    list of str
        One line per problem, sorted: a script with no row (``missing: NAME``) and a
        name on the page that is no script (``not a script: NAME``); empty when the
        page and the directory agree.
    """
    have = scripts(package)
    rows = set(ROW.findall(page))
    named = set(NAMED.findall(page))
    problems = [f"missing: {name}" for name in sorted(have - rows)]
    problems += [f"not a script: {name}" for name in sorted((named | rows) - have)]
    return problems


def _package(tmp_path: Path, modules: dict[str, str]) -> Path:
    """A ``benchmarks`` directory under ``tmp_path`` holding ``modules`` (path -> source)."""
    package = tmp_path / "benchmarks"
    for name, source in modules.items():
        path = package / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(source), encoding="utf-8")
    return package


MAIN = 'def main() -> int:\n    return 0\n\n\nif __name__ == "__main__":\n    main()\n'


def test_the_index_lists_every_script_and_no_other() -> None:
    page = INDEX.read_text(encoding="utf-8")
    assert index_problems(page, BENCHMARKS) == []


def test_the_repository_has_scripts_to_list() -> None:
    # A broken finder that returned nothing would let every index pass.
    found = scripts(BENCHMARKS)
    assert {"benchmarks.golden", "benchmarks.run", "benchmarks.mrpt.run"} <= found
    assert "benchmarks.__init__" not in found


def test_a_script_without_a_row_is_reported(tmp_path: Path) -> None:
    package = _package(tmp_path, {"__init__.py": "", "speed.py": MAIN, "mrpt/run.py": MAIN})
    page = "| `python -m benchmarks.speed --repeat 3` | measure |\n"
    assert index_problems(page, package) == ["missing: benchmarks.mrpt.run"]


def test_a_name_that_is_no_script_is_reported(tmp_path: Path) -> None:
    package = _package(tmp_path, {"speed.py": MAIN})
    page = (
        "| `python -m benchmarks.speed` | measure |\n"
        "| `python -m benchmarks.gone --x 1` | measure |\n"
        "Compare with `benchmarks.renamed`'s digests, [a page](2026-11-22-benchmarks.md).\n"
    )
    assert index_problems(page, package) == [
        "not a script: benchmarks.gone",
        "not a script: benchmarks.renamed",
    ]


def test_a_mention_in_prose_is_not_a_row(tmp_path: Path) -> None:
    package = _package(tmp_path, {"speed.py": MAIN})
    page = "Run `python -m benchmarks.speed` before a release.\n"
    assert index_problems(page, package) == ["missing: benchmarks.speed"]


def test_helpers_and_placeholders_need_no_row(tmp_path: Path) -> None:
    package = _package(
        tmp_path,
        {
            "__init__.py": MAIN,
            "shared.py": "def main() -> int:\n    return 0\n",
            "nested.py": 'def f() -> None:\n    if __name__ == "__main__":\n        pass\n',
            "speed.py": MAIN,
        },
    )
    page = "Run `python -m benchmarks.NAME`.\n| `python -m benchmarks.speed` | measure |\n"
    assert index_problems(page, package) == []
