"""Habits that keep the package readable as it grows (../shared/STYLE.md, section 7): functions under
60 lines outside the numeric kernels, and start-up that imports only what a command uses."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# Compiled per-ray loops: one function per kernel keeps numba's loop in one piece, where a call per
# step would cost more than the step.
NUMERIC_KERNELS = {"terra/sim/kernels.py:cast_kernel"}
MAX_LINES = 60


def long_functions() -> dict[str, int]:
    """`file:function` -> lines (def to last line) of every function of MAX_LINES lines or more."""
    found = {}
    for path in sorted((REPO / "terra").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines >= MAX_LINES:
                    found[f"{path.relative_to(REPO).as_posix()}:{node.name}"] = lines
    return found


def test_no_function_of_60_lines_or_more_outside_the_numeric_kernels():
    found = long_functions()
    assert set(found) - NUMERIC_KERNELS == set(), found
    assert all((REPO / name.split(":")[0]).is_file() for name in NUMERIC_KERNELS)  # the exemption names real files


def test_the_help_imports_no_numeric_or_model_library():
    code = (
        "import sys; from terra.cli import app; "
        "heavy = [m for m in ('numpy', 'scipy', 'sklearn', 'torch', 'numba', 'matplotlib', 'onnxruntime') "
        "if m in sys.modules]; print(','.join(heavy))"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == ""


def test_building_a_graph_imports_no_model_library():
    """`terra build` needs NumPy and SciPy; scikit-learn only for spectral regions, never torch."""
    code = (
        "import sys; import terra.graph.pipeline, terra.mapping.storage, terra.cli.build; "
        "print(','.join(m for m in ('sklearn', 'torch', 'numba', 'matplotlib') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == ""
