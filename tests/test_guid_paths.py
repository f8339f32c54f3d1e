"""The same scene built from two checkouts at different paths has the same GUID: no absolute path of the checkout
(the host libraries a model calls through casadi.external, a heightmap's library that the contact search's
library links) enters what the GUID hashes."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PROBE = """
import sys
sys.path.insert(0, sys.argv[1] + "/python")
from cedra.fmu import packaging
from cedra.models.scene import load_shipped
assert packaging.__file__.startswith(sys.argv[1]), packaging.__file__
print(packaging._generator().spec_guid(load_shipped(sys.argv[2]).spec()))
"""


def _checkout(root: Path) -> Path:
    root.mkdir(parents=True)
    for d in ("python", "fmu_src", "modelDescription"):
        shutil.copytree(REPO / d, root / d, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(REPO / "pyproject.toml", root / "pyproject.toml")
    return root


@pytest.mark.parametrize("scene", ["bump2d", "hills3d"])     # hills3d: the rim search's library links the heightmap's
def test_same_guid_from_two_checkouts(tmp_path, scene):
    a, b = _checkout(tmp_path / "one"), _checkout(tmp_path / "second" / "deeper")
    guids = [subprocess.run([sys.executable, "-c", PROBE, str(c), scene], cwd=tmp_path, capture_output=True,
                            text=True, check=True).stdout.strip() for c in (a, b)]
    assert guids[0].startswith("{") and guids[0] == guids[1]
