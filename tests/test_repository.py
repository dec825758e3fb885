"""The code reads like its paper: no function in windbench/ over 80 lines or with more than
12 parameters, no module docstring over 40 lines (what and why, with the equations; the
measurements live in experiments/), no timing figures in windbench's docstrings and
comments (speed-ups, "x against y ms": they live in experiments/results/, where they are
dated and remeasured), and no development history in the tree (issue numbers, numbered
work periods: that is what git history is for)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES, MAX_PARAMETERS, MAX_DOCSTRING = 80, 12, 40
HISTORY = re.compile(
    r"\bissues?\s*#?\d+"  # issue 6, issue #3, issues 4
    r"|\b(?:PR|pull request)\s*#?\d+"
    r"|\(#\d+\)"
    r"|(?<!scope=\")\bsessions?\b"
    r"|\bwork periods?\b"
    r"|\b(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|\d+(?:st|nd|rd|th))"
    r"\s+(?:round|period|session|stage)\b",
    re.IGNORECASE,
)
HISTORY_TREES = ("windbench", "conf", "experiments", "tests")
TIMING = re.compile(
    r"\bagainst\s+\d+(?:\.\d+)?\s*(?:ms|µs|s)\b"  # 0.19 against 0.06 ms
    r"|\d\s*(?:%|times)\s+(?:as\s+(?:fast|slow|costly)|faster|slower)"  # 30% faster
    r"|\d(?:\.\d+)?\s*(?:ms|µs)\s+(?:per|a)\s+(?:step|iteration|call|frame)\b",  # 2 ms per step
    re.IGNORECASE,
)


def _sources() -> list[Path]:
    return sorted((ROOT / "windbench").rglob("*.py"))


def _shape_faults(path: Path) -> list[str]:
    """What a module breaks of the size rules, one line each."""
    tree = ast.parse(path.read_text())
    faults = []
    doc = ast.get_docstring(tree, clean=False)
    if doc and len(doc.splitlines()) > MAX_DOCSTRING:
        faults.append(f"module docstring of {len(doc.splitlines())} lines")
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            a = node.args
            n_params = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
            n_params += (a.vararg is not None) + (a.kwarg is not None)
            n_lines = node.end_lineno - node.lineno + 1
            if n_lines > MAX_LINES or n_params > MAX_PARAMETERS:
                faults.append(
                    f"{node.name} (line {node.lineno}): {n_lines} lines, {n_params} parameters"
                )
    return faults


def _pattern_faults(path: Path, pattern: re.Pattern) -> list[str]:
    """Each match of ``pattern`` in a text file, with its line number."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:  # data files (netCDF, images)
        return []
    return [
        f"line {n}: {m.group(0)!r}"
        for n, line in enumerate(text.splitlines(), 1)
        for m in pattern.finditer(line)
    ]


def _tree_files() -> list[Path]:
    files = [ROOT / "README.md"]
    for tree in HISTORY_TREES:
        files += [
            p for p in (ROOT / tree).rglob("*") if p.is_file() and "__pycache__" not in p.parts
        ]
    return sorted(files)


def _relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def test_functions_and_module_docstrings_are_small():
    faults = {_relative(p): f for p in _sources() if (f := _shape_faults(p))}
    assert not faults, "\n".join(f"{path}: {'; '.join(f)}" for path, f in faults.items())


def test_no_development_history_in_the_tree():
    faults = {
        _relative(p): f
        for p in _tree_files()
        if p != Path(__file__).resolve() and (f := _pattern_faults(p, HISTORY))
    }
    assert not faults, "\n".join(f"{path}: {'; '.join(f)}" for path, f in faults.items())


def test_no_timing_figures_in_the_package():
    caught = [
        "(threads.py; 0.19 against 0.06 ms for the kernel)",
        "the backtrace got 25-30% faster, bit for bit the same",
        "a third of the time, 3 times as fast",
        "cost about 2 ms per step at 64^3",
    ]
    assert all(TIMING.search(text) for text in caught)
    assert not TIMING.search("Rayleigh damping time 1 ms, run at 60 frames per second")
    faults = {_relative(p): f for p in _sources() if (f := _pattern_faults(p, TIMING))}
    assert not faults, "\n".join(f"{path}: {'; '.join(f)}" for path, f in faults.items())
