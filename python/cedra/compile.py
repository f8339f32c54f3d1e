"""Compiling C with a cache that remembers: one object per translation unit, content-addressed. Every C compile
of the package goes through here: the FMUs' units (cedra.fmu.packaging), the host libraries the Python side loads
(cedra.models.host), the optimizer's equations, the benchmark's and the fuzzer's programs.

    compile_objects(jobs, obj_dir, workers) -> [object paths]     (jobs: CompileJob(source, flags, include_dir))
    link_library(jobs, lib, link_args)      -> lib                (the objects linked into one shared library)
    link_program(jobs, exe, link_args)      -> exe                (... into one executable)
    shared_library(source, flags, out_dir)  -> out_dir/<stem>-<key>.so

A utility at the bottom of the package, beside cedra.contract: it knows compilers and files, no model. Compiles
run in parallel, one per core unless told otherwise.

An object's key is the SHA-256 of what decides its bytes: the compiler's identity (its --version text and target),
the flags, the translation unit's own text and the text of every local header it includes ("..." includes found in
its include directory, recursively). System headers belong to the compiler, whose identity is in the key. Paths
are not: the same file compiled from two build trees or two checkouts is one entry.

The cache (CEDRA_CACHE, default ~/.cache/cedra; objects/ under it) holds <key>.o and <key>.sha256, the object's
own SHA-256. An entry whose object does not match its recorded hash (truncated, corrupted, or the sidecar missing)
is removed and compiled again, never linked. Entries are written under a temporary name and renamed into place,
so two builds that compile the same file at once both end with a whole object.
"""
from __future__ import annotations

import hashlib
import os
import re
import subprocess
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

CC = os.environ.get("CC", "gcc")
CACHE_ENV = "CEDRA_CACHE"
_INCLUDE = re.compile(rb'^[ \t]*#[ \t]*include[ \t]*"([^"]+)"', re.M)


class CompileError(RuntimeError):
    pass


@dataclass(frozen=True)
class CompileJob:
    source: Path                 # the translation unit
    flags: tuple[str, ...]       # compiler flags (without -c, -o and the include directory)
    include_dir: Path | None = None


@dataclass
class CompileStats:
    """What one compile_objects call did: files taken from the cache, files compiled, the compiles' CPU seconds."""
    cached: list[str] = field(default_factory=list)
    compiled: list[str] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)


def cache_dir() -> Path:
    root = os.environ.get(CACHE_ENV) or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "cedra"
    return Path(root) / "objects"


def run(cmd, cwd=None) -> str:
    """Run a compiler or linker command; CompileError with its output when it fails."""
    return run_timed(cmd, cwd)[0]


def run_timed(cmd, cwd=None) -> tuple[str, float]:
    """(stdout, the command's own CPU seconds: user + system of the child, from its rusage, so that commands run
    on several threads at once are each charged their own)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        p = subprocess.Popen([str(c) for c in cmd], cwd=cwd, stdout=out, stderr=err)
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(errors="replace"), err.read().decode(errors="replace")
    if p.returncode != 0:
        raise CompileError(f"{' '.join(map(str, cmd))} failed (rc {p.returncode}):\n{stdout}{stderr}")
    return stdout, usage.ru_utime + usage.ru_stime


@lru_cache(maxsize=None)
def compiler_identity(cc: str = CC) -> str:
    """The compiler's version text and target: a new compiler (or another one) gives other keys."""
    return run([cc, "--version"]) + run([cc, "-dumpmachine"])


def _unit_text(source: Path, include_dir: Path | None) -> bytes:
    """The translation unit's text and, in include order, every local header it reaches (each once)."""
    seen, parts = set(), []

    def add(path: Path):
        data = path.read_bytes()
        parts.append(path.name.encode() + b"\0" + data + b"\0")
        for m in _INCLUDE.finditer(data):
            name = m.group(1).decode()
            for d in (path.parent, include_dir):
                h = d / name if d is not None else None
                if h is not None and h.is_file() and h.resolve() not in seen:
                    seen.add(h.resolve())
                    add(h)
                    break

    seen.add(source.resolve())
    add(source)
    return b"".join(parts)


def object_key(job: CompileJob, cc: str = CC) -> str:
    h = hashlib.sha256()
    h.update(compiler_identity(cc).encode() + b"\0")
    h.update("\0".join(job.flags).encode() + b"\0")
    h.update(_unit_text(Path(job.source), job.include_dir))
    return h.hexdigest()


def cached_object(key: str, root: Path | None = None) -> bytes | None:
    """The cache's object for key if it is whole: its bytes, read once and checked against the recorded hash (the
    bytes checked are the bytes used, whatever another process does to the entry meanwhile); a damaged entry is
    removed."""
    root = root or cache_dir()
    obj, sha = root / f"{key}.o", root / f"{key}.sha256"
    try:
        data = obj.read_bytes()
    except FileNotFoundError:
        return None
    try:
        whole = sha.read_text().strip() == hashlib.sha256(data).hexdigest()
    except OSError:
        whole = False
    if not whole:
        for p in (obj, sha):
            try:
                p.unlink()
            except FileNotFoundError:
                pass
        return None
    return data


def compile_object(job: CompileJob, cc: str = CC, root: Path | None = None) -> tuple[bytes, bool, float]:
    """(the object's bytes, whether it was compiled now, the compile's CPU seconds); a compiled object is put into
    the cache."""
    root = root or cache_dir()
    key = object_key(job, cc)
    hit = cached_object(key, root)
    if hit is not None:
        return hit, False, 0.0
    root.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f"{key}.", suffix=".o.tmp", dir=root)
    os.close(fd)
    tmp = Path(tmp)
    sha_tmp = tmp.with_suffix(".sha.tmp")
    try:
        inc = ["-I", str(job.include_dir)] if job.include_dir is not None else []
        _, cpu = run_timed([cc, *job.flags, *inc, "-c", str(job.source), "-o", str(tmp)])
        data = tmp.read_bytes()
        sha_tmp.write_text(hashlib.sha256(data).hexdigest() + "\n")
        os.replace(tmp, root / f"{key}.o")         # the object first: a sidecar never names a missing object
        os.replace(sha_tmp, root / f"{key}.sha256")
    finally:
        for p in (tmp, sha_tmp):
            if p.exists():
                p.unlink()
    return data, True, cpu


_CPU_LOCK = threading.Lock()


def compile_objects(jobs: list[CompileJob], obj_dir: Path, workers: int | None = None, cc: str = CC,
                    stats: CompileStats | None = None) -> list[Path]:
    """Every job's object copied into obj_dir (<source stem>.o), in jobs' order: from the cache where it holds the
    object, compiled (largest source first, `workers` at a time) where it does not."""
    obj_dir = Path(obj_dir)
    obj_dir.mkdir(parents=True, exist_ok=True)
    workers = max(1, workers or os.cpu_count() or 1)
    order = sorted(range(len(jobs)), key=lambda k: -Path(jobs[k].source).stat().st_size)
    results: dict[int, Path] = {}

    def one(k):
        job = jobs[k]
        data, fresh, cpu = compile_object(job, cc)
        out = obj_dir / (Path(job.source).stem + ".o")
        out.write_bytes(data)
        if stats is not None:
            with _CPU_LOCK:
                (stats.compiled if fresh else stats.cached).append(Path(job.source).name)
                if fresh:
                    stats.seconds[Path(job.source).name] = cpu
        return k, out

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for k, out in pool.map(one, order):
            results[k] = out
    return [results[k] for k in range(len(jobs))]


def source_key(jobs: list[CompileJob], *extra: str) -> str:
    """The SHA-256 of the jobs' flags and texts (each unit with its local headers) and of `extra` (what else names
    the result, e.g. a library it links by file name), without the compiler: a name for what the jobs build that
    stays the same across checkouts, build trees and compiler updates (the objects under it are the cache's)."""
    h = hashlib.sha256()
    for job in jobs:
        h.update("\0".join(job.flags).encode() + b"\0")
        h.update(_unit_text(Path(job.source), job.include_dir))
    h.update("\0".join(extra).encode())
    return h.hexdigest()


def _link(jobs: list[CompileJob], out: Path, link_args, workers: int | None, cc: str,
          stats: CompileStats | None) -> Path:
    """The jobs' objects (compile_objects) linked with link_args into out, written under a temporary name and
    renamed into place: a loader or a second build never sees a partial file. Kept if out exists."""
    out = Path(out)
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.name}.") as d:
        objects = compile_objects(jobs, Path(d) / "obj", workers, cc, stats)
        tmp = Path(d) / out.name
        run([cc, "-o", str(tmp), *map(str, objects), *map(str, link_args)])
        os.replace(tmp, out)
    return out


def link_library(jobs: list[CompileJob], lib: Path, link_args=("-lm",), workers: int | None = None,
                 cc: str = CC, stats: CompileStats | None = None) -> Path:
    """The jobs compiled (through the object cache, in parallel) and linked into the shared library lib (-shared
    and then link_args after the objects). lib's name should change with what it holds (source_key): a process
    that loaded an older library never sees it replaced (the loader keeps a library by its path)."""
    return _link(jobs, lib, ("-shared", *link_args), workers, cc, stats)


def link_program(jobs: list[CompileJob], exe: Path, link_args=("-lm",), workers: int | None = None,
                 cc: str = CC, stats: CompileStats | None = None) -> Path:
    """The jobs compiled (through the object cache, in parallel) and linked into the executable exe."""
    return _link(jobs, exe, tuple(link_args), workers, cc, stats)


def shared_library(source: Path, flags: tuple[str, ...], out_dir: Path, cc: str = CC) -> Path:
    """source compiled (through the object cache) and linked into out_dir/<stem>-<key>.so, a name that changes
    with the object's key: a process that loaded an older library of the same stem never sees it replaced (the
    loader keeps a library by its path)."""
    job = CompileJob(Path(source), tuple(flags) + ("-fPIC",))
    lib = Path(out_dir) / f"{Path(source).stem}-{object_key(job, cc)[:16]}.so"
    return link_library([job], lib, ("-lm",), 1, cc)
