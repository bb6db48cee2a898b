"""The Rust core crosses into Python at one place: `htm.core` imports the extension `htm._core`,
nothing else in the package does, and the defaults and ranges Python states are the core's."""
import ast
from pathlib import Path

import htm.core as core

PACKAGE = Path(core.__file__).parent


def _imports_extension(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module == "htm._core":
            return True
        if isinstance(node, ast.ImportFrom) and node.module == "htm" and any(a.name == "_core" for a in node.names):
            return True
        if isinstance(node, ast.Import) and any(a.name == "htm._core" for a in node.names):
            return True
    return False


def test_only_htm_core_imports_the_extension():
    importers = sorted(str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if _imports_extension(p))
    assert importers == ["core.py"], importers


def test_the_boundary_check_sees_an_import(tmp_path):
    for line in ("from htm._core import Params", "from htm import _core", "import htm._core"):
        f = tmp_path / "m.py"
        f.write_text(line + "\n")
        assert _imports_extension(f), line
