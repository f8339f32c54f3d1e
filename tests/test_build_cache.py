"""The build that remembers: the object cache (cedra.fmu.compiler) and the FMUs' build stamps (cedra.fmu.packaging).

- an object's key covers the translation unit, the local headers it includes, the flags and the compiler, and not
  the path it is compiled from;
- a damaged cache entry (truncated, corrupted, its hash missing) is found by its hash and compiled again, never
  linked;
- an FMU is kept while its stamp matches and rebuilt when the scene or the FMU file changes.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from cedra.fmu import compiler, packaging
from cedra.fmu.compiler import CompileJob, CompileStats, compile_objects

UNIT = '#include "part.h"\nint cedra_test_value(void) { return PART_VALUE; }\n'


@pytest.fixture
def cache(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv(compiler.CACHE_ENV, str(root))
    return root / "objects"


def _unit(d: Path, value: int = 3) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "part.h").write_text(f"#define PART_VALUE {value}\n")
    (d / "unit.c").write_text(UNIT)
    return d / "unit.c"


def _job(src: Path, flags=("-O1", "-fPIC")) -> CompileJob:
    return CompileJob(src, tuple(flags), src.parent)


def test_key_covers_headers_and_flags_but_not_the_path(tmp_path, cache):
    a, b = _unit(tmp_path / "a"), _unit(tmp_path / "b")
    assert compiler.object_key(_job(a)) == compiler.object_key(_job(b))
    assert compiler.object_key(_job(a)) != compiler.object_key(_job(a, ("-O2", "-fPIC")))
    c = _unit(tmp_path / "c", value=4)                     # only the included header differs
    assert compiler.object_key(_job(a)) != compiler.object_key(_job(c))


def test_second_build_takes_every_object_from_the_cache(tmp_path, cache):
    src = _unit(tmp_path / "a")
    first, second = CompileStats(), CompileStats()
    o1 = compile_objects([_job(src)], tmp_path / "obj1", stats=first)
    o2 = compile_objects([_job(_unit(tmp_path / "b"))], tmp_path / "obj2", stats=second)
    assert first.compiled == ["unit.c"] and first.cached == []
    assert second.compiled == [] and second.cached == ["unit.c"]
    assert o1[0].read_bytes() == o2[0].read_bytes()


@pytest.mark.parametrize("damage", ["truncate", "flip", "no_hash"])
def test_a_damaged_entry_is_compiled_again_never_linked(tmp_path, cache, damage):
    src = _unit(tmp_path / "a")
    good = compile_objects([_job(src)], tmp_path / "obj1")[0].read_bytes()
    key = compiler.object_key(_job(src))
    entry = cache / f"{key}.o"
    if damage == "truncate":
        entry.write_bytes(good[: len(good) // 2])
    elif damage == "flip":
        entry.write_bytes(good[:100] + bytes([good[100] ^ 0xFF]) + good[101:])
    else:
        (cache / f"{key}.sha256").unlink()
    assert compiler.cached_object(key) is None             # found by its hash, removed
    stats = CompileStats()
    out = compile_objects([_job(src)], tmp_path / "obj2", stats=stats)[0]
    assert stats.compiled == ["unit.c"]
    assert out.read_bytes() == good


def test_a_failing_compile_leaves_no_entry(tmp_path, cache):
    d = tmp_path / "bad"
    d.mkdir()
    (d / "unit.c").write_text("int broken( {\n")
    with pytest.raises(compiler.CompileError, match="unit.c"):
        compile_objects([_job(d / "unit.c")], tmp_path / "obj")
    assert not cache.exists() or not any(cache.iterdir())


def test_fmu_stamp_keeps_and_rebuilds(tmp_path, cache, monkeypatch):
    """The toy model has no scene: the stamp functions are exercised on a controller, the smallest shipped FMU."""
    out = tmp_path / "build"
    lines = []
    path = packaging.ensure_fmu("drive2d", out, log=lines.append)
    assert lines and "missing" in lines[0]
    assert packaging.fmu_state("drive2d", out)[2] == "up to date"
    mtime = path.stat().st_mtime_ns
    lines.clear()
    assert packaging.ensure_fmu("drive2d", out, log=lines.append) == path
    assert lines == [] and path.stat().st_mtime_ns == mtime            # kept as it is
    path.write_bytes(path.read_bytes() + b"\0")                         # not the file its stamp hashed
    assert packaging.fmu_state("drive2d", out)[2] == "stale"
    packaging.ensure_fmu("drive2d", out, log=lines.append)
    assert "stale" in lines[0] and "0 files compiled" in lines[1]       # every object from the cache
    assert packaging.fmu_state("drive2d", out)[2] == "up to date"
    monkeypatch.setattr(packaging, "sources_digest", lambda: "other sources")
    assert packaging.fmu_state("drive2d", out)[2] == "stale"


def test_scene_key_ignores_where_the_scene_file_lives(tmp_path):
    from importlib import resources
    from cedra.models.scene import load
    scenes = Path(str(resources.files("cedra.models.scenes")))
    text, grid = (scenes / "hills3d.toml").read_text(), (scenes / "hills3d.txt").read_bytes()
    keys = []
    for d in ("one", "two"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "hills3d.txt").write_bytes(grid)
        (tmp_path / d / "hills3d.toml").write_text(text)
        keys.append(packaging.build_key(load(tmp_path / d / "hills3d.toml")))
    assert keys[0] == keys[1]
    (tmp_path / "two" / "hills3d.txt").write_bytes(grid + b"\n# edited\n")
    assert packaging.build_key(load(tmp_path / "two" / "hills3d.toml")) != keys[0]     # the grid is in the key


def test_object_cache_dir_default(monkeypatch, tmp_path):
    monkeypatch.delenv(compiler.CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compiler.cache_dir() == tmp_path / "cedra" / "objects"
    assert os.fspath(compiler.cache_dir()).startswith(os.fspath(tmp_path))


def test_two_processes_asking_at_once_build_once(tmp_path, cache):
    """Two processes that need the same missing FMU at once (xdist workers, a sweep and a script): one builds it
    under the lock, the other then finds it up to date."""
    import subprocess
    import sys
    code = ("import sys; from cedra.fmu.packaging import ensure_fmu; "
            "ensure_fmu('drive2d', sys.argv[1], log=lambda line: print(line, flush=True))")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1] / "python"))
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "build")], stdout=subprocess.PIPE,
                              text=True, env=env) for _ in range(2)]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sum(o.count("building") for o in outs) == 1, outs
    assert packaging.fmu_state("drive2d", tmp_path / "build")[2] == "up to date"
