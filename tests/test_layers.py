"""cedra.mechanics and cedra.rover sit below the build: they compile nothing, run no program and import nothing from
a higher layer (the host libraries mechanics calls come from the builders cedra.models.host hands it)."""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "cedra"
BELOW_THE_BUILD = {"mechanics": ("cedra.contract", "cedra.mechanics"),
                   "rover": ("cedra.contract", "cedra.mechanics", "cedra.rover")}
RUNS_PROGRAMS = {"subprocess", "multiprocessing", "distutils", "setuptools", "cffi"}
OS_RUNNERS = {"system", "popen", "execv", "execve", "execvp", "execl", "execlp", "spawnv", "spawnl", "spawnvp",
              "posix_spawn", "posix_spawnp", "fork"}
COMPILERS = ("gcc", "cc", "clang", "g++", "tcc")


def _modules():
    return [(pkg, p) for pkg in BELOW_THE_BUILD for p in sorted((PACKAGE / pkg).glob("*.py"))]


def _findings(pkg: str, path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    allowed = BELOW_THE_BUILD[pkg]
    found = []
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:                              # relative: inside its own package
                base = f"cedra.{pkg}.{base}".rstrip(".")
            names = [base] + [f"{base}.{a.name}" for a in node.names if base == "cedra"]
        for name in names:
            top = name.split(".")[0]
            if top in RUNS_PROGRAMS:
                found.append(f"line {node.lineno}: imports {name}")
            if top == "cedra" and name != "cedra" and not any(name == a or name.startswith(a + ".")
                                                              for a in allowed):
                found.append(f"line {node.lineno}: imports {name} (a layer above or beside {pkg})")
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "os" \
                and node.attr in OS_RUNNERS:
            found.append(f"line {node.lineno}: os.{node.attr}")
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            first = node.value.strip().split(" ")[0] if node.value.strip() else ""
            if Path(first).name in COMPILERS:
                found.append(f"line {node.lineno}: names the compiler {node.value!r}")
    return found


@pytest.mark.parametrize("pkg, path", _modules(), ids=lambda v: v.name if isinstance(v, Path) else v)
def test_compiles_nothing_and_imports_no_higher_layer(pkg, path):
    assert _findings(pkg, path) == []


def test_the_check_finds_a_compiler_call(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import subprocess\nfrom cedra.fmu.compiler import run\nfrom cedra import compile\n"
                   "import os\nos.system('x')\nsubprocess.run(['gcc', '-c', 'a.c'])\n")
    found = _findings("mechanics", bad)
    assert any("subprocess" in f for f in found)
    assert any("cedra.fmu.compiler" in f for f in found)
    assert any("cedra.compile" in f for f in found)
    assert any("os.system" in f for f in found)
    assert any("'gcc'" in f for f in found)


def test_importing_them_loads_no_compiler():
    """Every module of both packages imported in a fresh interpreter: neither the compile helper nor a higher layer
    is among the modules loaded."""
    mods = [f"cedra.{pkg}.{p.stem}" for pkg, p in _modules() if p.stem != "__init__"]
    probe = ("import importlib, sys\n"
             f"for m in {mods!r}: importlib.import_module(m)\n"
             "print(' '.join(sorted(m for m in sys.modules if m == 'cedra.compile' or m.startswith(("
             "'cedra.fmu', 'cedra.models', 'cedra.run', 'cedra.sweep', 'cedra.optimize', 'cedra.reports')))))\n")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(PACKAGE.parent)}, check=True)
    assert r.stdout.strip() == ""


def test_without_cedra_models_the_host_libraries_are_refused_by_name():
    """Used alone, mechanics has no builder for its host libraries: it says which import provides one."""
    probe = ("from cedra.mechanics import heightmap, rim\n"
             "for call, error in ((heightmap.host_library, heightmap.HeightmapError),\n"
             "                    (lambda: rim._library('int x;'), rim.RimBuildError)):\n"
             "    try:\n"
             "        call()\n"
             "    except error as e:\n"
             "        print(e)\n")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(PACKAGE.parent)}, check=True)
    lines = r.stdout.splitlines()
    assert len(lines) == 2 and all("import cedra.models" in ln for ln in lines), r.stdout
