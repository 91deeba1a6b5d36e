"""The layering of the package: imports flow scene → deck → run → dump → stress → pictures.

``lint-imports`` (import-linter) checks the contracts in pyproject.toml: each layer imports only
the layers below it, the LAMMPS engine's runner → callback → deck, and no import cycle between
sibling modules (function-level imports included).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from conftest import HANG_S

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_are_kept():
    exe = Path(sys.executable).parent / "lint-imports"
    proc = subprocess.run([str(exe), "--config", str(ROOT / "pyproject.toml")], cwd=ROOT,
                          capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout
