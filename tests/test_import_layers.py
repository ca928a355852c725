"""The package's layers: no module imports from a layer above its own (issue 15).

Every import statement of every module under ``jaxnav/`` is read, including those inside
functions. The layers (docs/architecture.md): ``geodesy``, ``attitude`` and the package root at
the bottom; then ``ins`` and ``gnss``; ``filter``; ``sim``; ``io`` (files only: the bottom layer and
``gnss``); ``study``; ``apps`` and ``cli`` on top. The imports that still point the wrong way are
listed in ``KNOWN_UPWARD`` with the work that removes them; the test fails on any other, and on a
listed one that has gone (so the list only shrinks).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxnav"
BOTTOM = {"jaxnav", "geodesy", "attitude", "core"}
ALLOWED = {
    "ins": BOTTOM,
    "gnss": BOTTOM,
    "filter": BOTTOM | {"ins", "gnss"},
    "sim": BOTTOM | {"ins", "gnss", "filter"},
    "io": BOTTOM | {"gnss"},
    "study": BOTTOM | {"ins", "gnss", "filter", "sim", "io"},
    "apps": BOTTOM | {"ins", "gnss", "filter", "sim", "io", "study"},
}
# (importing file, imported module) pairs still allowed to point up: none since the last five
# were removed (issue 15). A new one may only be added here with the step that will remove it.
KNOWN_UPWARD: set[tuple[str, str]] = set()


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "jaxnav"


def _imports(path: Path, module: str):
    """(line, imported module) of every import in the file, relative ones resolved."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                if path.name != "__init__.py":
                    base = base[:-1]
                base = base[: len(base) - (node.level - 1)]
                yield node.lineno, ".".join(base + ([node.module] if node.module else []))
            elif node.module:
                yield node.lineno, node.module


def upward_imports() -> dict[tuple[str, str], int]:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        module = ".".join(("jaxnav", *rel.with_suffix("").parts)).removesuffix(".__init__")
        layer = _layer(module)
        if layer not in ALLOWED:
            continue  # the bottom layer imports nothing of ours; apps and cli may import all
        for line, target in _imports(path, module):
            if target.split(".")[0] != "jaxnav":
                continue
            to = _layer(target)
            if to != layer and to not in ALLOWED[layer]:
                found[(str(rel), target)] = line
    return found


def test_no_import_points_up_a_layer():
    found = upward_imports()
    new = {f"jaxnav/{f}:{line} imports {t}" for (f, t), line in found.items()
           if (f, t) not in KNOWN_UPWARD}
    assert not new, "imports that point up a layer:\n" + "\n".join(sorted(new))
    gone = KNOWN_UPWARD - set(found)
    assert not gone, f"fixed: remove from KNOWN_UPWARD: {sorted(gone)}"


def test_the_scanner_sees_imports_inside_functions(tmp_path):
    """An upward import inside a function body is found, a sibling-package one is not."""
    pkg = tmp_path / "jaxnav" / "ins"
    pkg.mkdir(parents=True)
    f = pkg / "x.py"
    f.write_text("import numpy\nfrom . import riss\n\ndef g():\n    from ..study import sweep\n")
    got = list(_imports(f, "jaxnav.ins.x"))
    assert got == [(1, "numpy"), (2, "jaxnav.ins"), (5, "jaxnav.study")]
    assert _layer("jaxnav.study") not in ALLOWED["ins"]
