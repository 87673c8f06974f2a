"""Rules of the code base a reader relies on, checked on the source itself: modules that read in one
sitting, and tuned numbers that say why they are what they are."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "hybridpose"
MODULES = sorted(PACKAGE.rglob("*.py"))
MAX_LINES = 500


def _numeric(node) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
    if isinstance(node, ast.UnaryOp):
        return _numeric(node.operand)
    if isinstance(node, ast.BinOp):
        return _numeric(node.left) and _numeric(node.right)
    if isinstance(node, ast.Tuple):
        return bool(node.elts) and all(_numeric(e) for e in node.elts)
    return False


def _constants(tree: ast.Module):
    """(line, names) of each module-level assignment of numbers to UPPER_CASE names."""
    for node in tree.body:
        if isinstance(node, ast.Assign) and _numeric(node.value):
            names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            names += [e.id for t in node.targets if isinstance(t, ast.Tuple) for e in t.elts if isinstance(e, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and node.value is not None and _numeric(node.value) \
                and isinstance(node.target, ast.Name):
            names = [node.target.id]
        else:
            continue
        names = [n for n in names if n.upper() == n]
        if names:
            yield node, names


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_a_module_reads_in_one_sitting(path):
    assert len(path.read_text().splitlines()) <= MAX_LINES


def test_every_tuned_number_says_why():
    """A module-level numeric constant carries a comment on its line or the line above, or its module's
    docstring names it."""
    silent = []
    for path in MODULES:
        source = path.read_text()
        lines, tree = source.splitlines(), ast.parse(source)
        doc = ast.get_docstring(tree) or ""
        for node, names in _constants(tree):
            first, last = node.lineno - 1, node.end_lineno - 1
            commented = "#" in lines[first] or "#" in lines[last] or (first > 0 and lines[first - 1].lstrip().startswith("#"))
            if not commented and not any(re.search(rf"\b{n}\b", doc) for n in names):
                silent.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {', '.join(names)}")
    assert not silent, "constants without a why: " + "; ".join(silent)
