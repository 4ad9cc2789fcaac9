"""The layers of the house (pyproject.toml, [tool.importlinter]): the command line above the systems, the systems
above the file formats and the engine core, the core above the kernels and the schemas; the core imports no system
and no system's kernels; no system imports another; the studio films without any system's stages. Checked by
import-linter over every import, those inside functions too."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def lint_imports() -> subprocess.CompletedProcess:
    command = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    if command is None:
        pytest.fail("lint-imports is not installed; install the test extras: pip install -e '.[test]'")
    return subprocess.run([command, "--config", str(ROOT / "pyproject.toml")], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_every_import_contract_is_kept():
    proc = lint_imports()
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout
    for contract in ("layers: cli > systems > formats > engine core > kernels > schemas",
                     "the engine core imports no system's kernels", "no system imports another",
                     "the studio films without any system's stages"):
        assert f"{contract} KEPT" in proc.stdout
