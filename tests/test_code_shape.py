"""The shape of the code: no function or method in src/pipemap longer than MAX_FUNCTION_LINES."""

from __future__ import annotations

import ast
from pathlib import Path

MAX_FUNCTION_LINES = 80
REPOSITORY = Path(__file__).resolve().parents[1]
SOURCE = REPOSITORY / "src" / "pipemap"


def long_functions(root: Path, limit: int) -> list[tuple[Path, str, int]]:
    """(path, qualified name, lines from `def` to the last line) of every function or method, nested ones
    included, in the .py files under `root` that is longer than `limit` lines."""
    found = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        stack = [(node, "") for node in tree.body]
        while stack:
            node, prefix = stack.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = prefix + node.name
                if not isinstance(node, ast.ClassDef):
                    length = node.end_lineno - node.lineno + 1
                    if length > limit:
                        found.append((path, name, length))
                stack.extend((child, name + ".") for child in ast.iter_child_nodes(node))
            else:
                stack.extend((child, prefix) for child in ast.iter_child_nodes(node))
    return sorted(found)


def test_no_function_is_longer_than_the_limit():
    assert SOURCE.is_dir(), SOURCE
    offenders = long_functions(SOURCE, MAX_FUNCTION_LINES)
    assert not offenders, f"functions over {MAX_FUNCTION_LINES} lines (split them into named steps):\n" + "\n".join(
        f"  {path.relative_to(REPOSITORY).as_posix()} {name}: {length} lines" for path, name, length in offenders)

