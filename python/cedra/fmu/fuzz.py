"""Sanitizer fuzzing of a cedra FMU: `python -m cedra fuzz <scene|file.fmu> [--sequences N] [--seed S] [--seconds T]`.

The FMU's sources/*.c are compiled together with tools/fuzz/fmu_fuzz.c into one executable (the fmi2 functions
linked in, no dlopen), by default with AddressSanitizer and UndefinedBehaviorSanitizer; the executable is cached
under build/fuzz/<model>/<variant>-<hash of the sources, the fuzzer and the flags>/. The executable drives random
call sequences and checks the invariants listed at the top of fmu_fuzz.c. A sanitizer aborts the process; the
runner then reports the sequence that was running (the executable prints "SEQ <seed>" before each one and the
call from a sanitizer death callback) and, with keep_going, goes on with the next seed.

The same executable has a leak mode (--cycles N) and a thread mode (--threads N); `run_mode` runs those for the
tests (tests/test_fmu_leaks.py, tests/test_fmu_threads.py).
"""
from __future__ import annotations

import argparse
import fcntl
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

from cedra.compile import CC, CompileError, CompileJob, compile_objects, run
from cedra.fmu.codegen import GENERATED_CFLAGS_RELAX, is_generated
from cedra.fmu.packaging import REPO_ROOT

FUZZ_C = REPO_ROOT / "tools" / "fuzz" / "fmu_fuzz.c"
CACHE = REPO_ROOT / "build" / "fuzz"
SANITIZE = ["-fsanitize=address,undefined,float-cast-overflow", "-fno-sanitize-recover=all",
            "-fno-omit-frame-pointer"]
VARIANTS = {
    "asan": ["-g", "-O1", *SANITIZE],
    "plain": ["-g", "-O1"],              # for valgrind (which cannot run sanitized code)
}
FMU_CFLAGS = ["-std=c99", "-Wall", "-Wextra"]             # the FMU's own C: its build has -Werror already
FUZZER_CFLAGS = ["-std=gnu99", "-Wall", "-Wextra", "-Werror"]   # gnu: setitimer, pthread barriers
# calloc semantics for the FMU's allocator (NULL instead of an ASan abort); leaks judged at exit
ASAN_OPTIONS = "detect_leaks=1:allocator_may_return_null=1:halt_on_error=1:symbolize=1"
UBSAN_OPTIONS = "print_stacktrace=1:halt_on_error=1"


class FuzzBuildError(RuntimeError):
    pass


# ----------------------------------------------------------------------------------------------------- build

def resolve_fmu(target: str, build_dir=REPO_ROOT / "build") -> Path:
    """A .fmu path, or a shipped scene name -> build/<scene>.fmu (built first if it is missing)."""
    if target.endswith(".fmu"):
        path = Path(target)
        if not path.exists():
            raise FileNotFoundError(target)
        return path.resolve()
    path = Path(build_dir) / f"{target}.fmu"
    if not path.exists():
        from cedra.fmu.packaging import build_fmu
        from cedra.models.scene import load_shipped
        path = build_fmu(load_shipped(target).spec(), Path(build_dir))
    return path.resolve()


def _model_name(z: zipfile.ZipFile, fmu: Path) -> str:
    m = re.search(rb'modelIdentifier="([^"]+)"', z.read("modelDescription.xml"))
    return m.group(1).decode() if m else fmu.stem


def _compile(jobs: list[CompileJob], obj_dir: Path) -> list[Path]:
    """The jobs' objects in obj_dir (cedra.compile: in parallel, through the object cache)."""
    try:
        return compile_objects(jobs, obj_dir)
    except CompileError as e:
        raise FuzzBuildError(str(e)) from None


def _link(cmd):
    try:
        run(cmd)
    except CompileError as e:
        raise FuzzBuildError(str(e)) from None


def _locked_build(out: Path, make) -> Path:
    """Builds the directory `out` once: `make(tmp)` fills a temporary directory that is then renamed to `out`.
    With pytest -n 2 the second worker waits for the first and reuses its result."""
    if out.exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if out.exists():
            return out
        tmp = Path(tempfile.mkdtemp(prefix=out.name + ".", dir=out.parent))
        try:
            make(tmp)
            tmp.rename(out)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp)
    return out


def build(fmu, variant: str = "asan", defines=(), cache=CACHE) -> Path:
    """The fuzzer executable for `fmu` (cached): every sources/*.c of the FMU plus fmu_fuzz.c, `variant` flags,
    `defines` (e.g. "FUZZ_PLANT_NOOP_STEP") for fmu_fuzz.c. The FMU's objects are cached apart from the
    executable, so fuzzer variants (the planted bugs) do not recompile the generated model."""
    fmu = Path(fmu)
    flags = VARIANTS[variant]
    with zipfile.ZipFile(fmu) as z:
        model = _model_name(z, fmu)
        sources = {n[len("sources/"):]: z.read(n) for n in z.namelist()
                   if n.startswith("sources/") and not n.endswith("/")}
    cfiles = sorted(n for n in sources if n.endswith(".c"))
    if not cfiles:
        raise FuzzBuildError(f"{fmu} has no sources/*.c")
    h = hashlib.sha256()
    for name in sorted(sources):
        h.update(name.encode() + b"\0" + sources[name] + b"\0")
    h.update(repr((flags, FMU_CFLAGS, GENERATED_CFLAGS_RELAX)).encode())
    src_key = h.hexdigest()
    h.update(FUZZ_C.read_bytes())
    h.update(repr((FUZZER_CFLAGS, sorted(defines))).encode())
    tag = "-".join([variant, *(d.lower().replace("fuzz_plant_", "plant-") for d in sorted(defines))])
    root = Path(cache) / model

    def make_objects(tmp: Path):
        src = tmp / "sources"
        src.mkdir()
        for name, data in sources.items():
            (src / name).write_bytes(data)

        def job(name):
            extra = GENERATED_CFLAGS_RELAX + ["-DCASADI_SYMBOL_EXPORT="] if is_generated(name) else []
            return CompileJob(src / name, (*FMU_CFLAGS, *flags, *extra), src)

        _compile([job(n) for n in cfiles], tmp)

    objdir = _locked_build(root / f"obj-{variant}-{src_key[:16]}", make_objects)

    def make_exe(tmp: Path):
        [o] = _compile([CompileJob(FUZZ_C, (*FUZZER_CFLAGS, *flags, *(f"-D{d}" for d in defines)),
                                   objdir / "sources")], tmp)
        objects = [str(objdir / (Path(n).stem + ".o")) for n in cfiles]
        _link([CC, *flags, "-o", str(tmp / "fmu_fuzz"), str(o), *objects, "-lm", "-pthread"])
        o.unlink()

    return _locked_build(root / f"{tag}-{h.hexdigest()[:16]}", make_exe) / "fmu_fuzz"


def resources_uri(fmu, cache=CACHE) -> str | None:
    """file: URI of the FMU's resources/ extracted under the cache (None if it has none)."""
    fmu = Path(fmu)
    with zipfile.ZipFile(fmu) as z:
        items = {n: z.read(n) for n in z.namelist() if n.startswith("resources/") and not n.endswith("/")}
        model = _model_name(z, fmu)
    if not items:
        return None
    h = hashlib.sha256(b"".join(n.encode() + b"\0" + d for n, d in sorted(items.items()))).hexdigest()[:16]
    root = Path(cache) / model / f"resources-{h}"
    if not (root / "resources").exists():
        tmp = Path(tempfile.mkdtemp(prefix=root.name + ".", dir=root.parent if root.parent.exists() else None))
        for n, d in items.items():
            (tmp / n).parent.mkdir(parents=True, exist_ok=True)
            (tmp / n).write_bytes(d)
        root.parent.mkdir(parents=True, exist_ok=True)
        try:
            tmp.rename(root)
        except OSError:           # another process extracted it first
            shutil.rmtree(tmp)
    return (root / "resources").as_uri() + "/"


def sanitizer_env(extra: dict | None = None) -> dict:
    env = dict(os.environ)
    env["ASAN_OPTIONS"] = ASAN_OPTIONS
    env["UBSAN_OPTIONS"] = UBSAN_OPTIONS
    env.update(extra or {})
    return env


def run_mode(fmu, args, variant="asan", defines=(), resources=None, env=None, timeout=900, wrapper=()):
    """Runs the executable for `fmu` with `args` (e.g. ["--cycles", "50"]); resources: list of file: URIs
    (default: the FMU's own). Returns the CompletedProcess (text)."""
    exe = build(fmu, variant, defines)
    if resources is None:
        uri = resources_uri(fmu)
        resources = [uri] if uri else []
    cmd = [*wrapper, str(exe), *map(str, args)]
    for uri in resources:
        cmd += ["--resources", uri]
    return subprocess.run(cmd, capture_output=True, text=True, env=sanitizer_env(env), timeout=timeout)


# ------------------------------------------------------------------------------------------------------ fuzz

@dataclass
class Finding:
    seed: int | None
    call: int | None
    text: str

    def kind(self) -> str:
        """the class of a finding: the invariant and the function, for (e) the fields changed, for a sanitizer
        report its reason without numbers"""
        inv = re.match(r"\(([a-h])\)", self.text)
        fn = re.search(r"\[in (fmi2\w+)", self.text)
        if inv:
            k = f"({inv.group(1)}) {fn.group(1) if fn else ''}"
            if inv.group(1) in "bcdfg":
                k += " " + re.sub(r"0x[0-9a-f]+|[-+]?\d+(\.\d+)?(e[-+]?\d+)?|-?nan|-?inf", "#",
                                  re.sub(r"\[in .*$", "", self.text[4:]))[:80].strip()
            return k
        t = re.sub(r"\[in .*$", "", self.text)
        t = re.sub(r"0x[0-9a-f]+|[-+]?\d+(\.\d+)?(e[-+]?\d+)?|-?nan|-?inf", "#", t)
        return (t[:110].strip() + (f" in {fn.group(1)}" if fn else "")).strip()


@dataclass
class FuzzResult:
    target: str
    exe: Path
    sequences: int = 0
    calls: int = 0
    checks: int = 0
    seconds: float = 0.0
    processes: int = 0
    steps_ok: int = 0
    call_limit: float = 0.0
    findings: list[Finding] = field(default_factory=list)

    def summary(self) -> str:
        rate = self.sequences / self.seconds if self.seconds > 0 else 0.0
        text = (f"{self.target}: {self.sequences} sequences, {self.calls} calls ({self.steps_ok} DoSteps OK), "
                f"{len(self.findings)} findings, {self.seconds:.1f} s ({rate:.1f} sequences/s)")
        hung = sum(f.text.startswith("(h)") for f in self.findings) * self.call_limit
        if hung > 0 and self.seconds > hung:   # calls stopped at the limit: their time says nothing of the rate
            text += (f"; {hung:.0f} s of it in calls stopped at the {self.call_limit:g} s limit, "
                     f"{self.sequences / (self.seconds - hung):.1f} sequences/s in the rest")
        return text

    def report(self, max_kinds: int = 20) -> str:
        lines = [self.summary()]
        kinds: dict[str, list[Finding]] = {}
        for f in self.findings:
            kinds.setdefault(f.kind(), []).append(f)
        if kinds:
            lines.append(f"{len(kinds)} kinds of findings (count, kind, first occurrence):")
        for k, fs in list(kinds.items())[:max_kinds]:
            f = fs[0]
            lines.append(f"  {len(fs)} x {k}\n      seed={f.seed} call={f.call}: {f.text[:600]}")
        if len(kinds) > max_kinds:
            lines.append(f"  ... {len(kinds) - max_kinds} more kinds")
        if self.findings:
            f = self.findings[0]
            lines.append(f"replay: python -m cedra fuzz {self.target} --seed {f.seed} --sequences 1 --trace")
        return "\n".join(lines)


_FINDING = re.compile(r"FINDING seed=(\d+) call=(-?\d+) inst=(-?\d+): (.*)")
_SANITIZER = re.compile(r"SANITIZER seed=(\d+) call=(-?\d+) inst=(-?\d+): (.*)")
_DONE = re.compile(r"DONE sequences=(\d+) calls=(\d+) checks=(\d+) findings=(\d+) seconds=\S+ dosteps_ok=(\d+)")


def sanitizer_summary(stderr: str) -> str:
    """The sanitizer's one-line reason and the first frames in the FMU's or the fuzzer's code."""
    lines = stderr.splitlines()
    head = next((ln.strip() for ln in lines if "runtime error:" in ln or re.search(r"ERROR: \w+Sanitizer", ln)),
                None)
    if head is None:
        return "\n".join(lines[-5:]) or "(no output)"
    head = re.sub(r"^.*/sources/", "", head)
    head = re.sub(r"==\d+==", "", head).strip()
    frames = [re.sub(r"^\s*#\d+ 0x[0-9a-f]+ in ", "", ln).strip() for ln in lines
              if re.match(r"\s*#\d+ 0x", ln) and ("/sources/" in ln or "fmu_fuzz.c" in ln)][:4]
    frames = [re.sub(r"/\S*/(sources/|tools/fuzz/)", "", f) for f in frames]
    return head + (" | " + " < ".join(frames) if frames else "")


def _locate(exe, seed: int, uri: str | None, call_limit: float) -> tuple[int | None, str]:
    """Replays sequence `seed` alone with --trace: the last call it started before dying, and whether the death
    reproduced. (libubsan has its own copy of the sanitizer runtime, so the death callback the executable sets
    in libasan does not run for UBSan reports: the replay finds the call instead.)"""
    cmd = [str(exe), "--seed", str(seed), "--sequences", "1", "--trace", "--call-limit", str(call_limit)]
    if uri:
        cmd += ["--resources", uri]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, env=sanitizer_env(), timeout=call_limit * 4 + 60)
    except subprocess.TimeoutExpired:
        return None, "the replay did not finish"
    calls = re.findall(r"^  #(\d+) inst -?\d+: (.*)$", p.stdout, re.M)
    if "DONE" in p.stdout or not calls:
        return None, "did not reproduce alone"
    return int(calls[-1][0]), calls[-1][1]


def fuzz(fmu, target: str | None = None, sequences: int | None = None, seed: int = 1,
         seconds: float | None = None, call_limit: float = 10.0, keep_going: bool = True, defines=(),
         echo=None) -> FuzzResult:
    """Runs the fuzzer until `sequences` sequences ran or `seconds` passed (either may be None, not both).
    A sanitizer abort or a hang ends a process: with keep_going the next process starts at the next seed."""
    if sequences is None and seconds is None:
        sequences = 1000
    exe = build(fmu, "asan", defines)
    uri = resources_uri(fmu)
    res = FuzzResult(target or Path(fmu).stem, exe, call_limit=call_limit)
    t0 = time.monotonic()
    next_seed, left = seed, sequences
    while True:
        elapsed = time.monotonic() - t0
        if (seconds is not None and elapsed >= seconds) or (left is not None and left <= 0):
            break
        cmd = [str(exe), "--seed", str(next_seed), "--sequences", str(left if left is not None else 10 ** 15),
               "--call-limit", str(call_limit)]
        if seconds is not None:
            cmd += ["--seconds", f"{seconds - elapsed:.3f}"]
        if keep_going:
            cmd.append("--keep-going")
        if uri:
            cmd += ["--resources", uri]
        hard = None if seconds is None else seconds - elapsed + call_limit + 60
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, env=sanitizer_env(), timeout=hard)
            out, err, rc = p.stdout, p.stderr, p.returncode
        except subprocess.TimeoutExpired as e:
            out = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
            err, rc = "killed by the runner's timeout", None
        res.processes += 1
        seqs = [int(m.group(1)) for m in re.finditer(r"^SEQ (\d+)", out, re.M)]
        before = [(int(m.group(1)), int(m.group(2))) for m in
                  re.finditer(r"^SEQ \d+ calls=(\d+) dosteps_ok=(\d+)", out, re.M)]
        last_seed = seqs[-1] if seqs else next_seed
        for m in _FINDING.finditer(out):
            res.findings.append(Finding(int(m.group(1)), int(m.group(2)), m.group(4)))
            if echo:
                echo(f"finding: seed={m.group(1)} call={m.group(2)}: {m.group(4)}")
        done = _DONE.search(out)
        res.sequences += int(done.group(1)) if done else len(seqs)
        res.calls += int(done.group(2)) if done else (before[-1][0] if before else 0)
        res.checks += int(done.group(3)) if done else 0
        res.steps_ok += int(done.group(5)) if done else (before[-1][1] if before else 0)
        if done and rc == 0:
            break
        if done:                      # finished its budget with findings, or LeakSanitizer at exit
            if "LeakSanitizer" in err:
                res.findings.append(Finding(None, None, "LeakSanitizer at exit: " + sanitizer_summary(err)))
            break
        # the process died inside sequence last_seed: a sanitizer report, the call limit, or a crash
        died_of_limit = any(f.seed == last_seed and f.text.startswith("(h)") for f in res.findings)
        if not died_of_limit:
            m = _SANITIZER.search(out)
            call, where = (int(m.group(2)), m.group(4)) if m else _locate(exe, last_seed, uri, call_limit)
            if rc is None:
                what = "killed: no answer within the runner's budget"
            elif rc < 0:
                what = f"killed by signal {-rc}: {sanitizer_summary(err)}"
            else:
                what = f"sanitizer: {sanitizer_summary(err)}"
            what += f" [in {where}]"
            res.findings.append(Finding(last_seed, call, what))
            res.calls += call or 0
            if echo:
                echo(f"finding: seed={last_seed} call={call}: {what}")
        if not keep_going:
            break
        if left is not None:
            left -= len(seqs)
        next_seed = last_seed + 1
    res.seconds = time.monotonic() - t0
    return res


def main(args) -> int:
    fmu = resolve_fmu(args.target, args.build)
    if args.trace:   # one sequence, every call and message: the replay of a finding
        exe = build(fmu, "asan")
        uri = resources_uri(fmu)
        cmd = [str(exe), "--seed", str(args.seed), "--sequences", str(args.sequences or 1), "--trace",
               "--call-limit", str(args.call_limit)] + (["--resources", uri] if uri else [])
        return subprocess.run(cmd, env=sanitizer_env()).returncode
    t0 = time.monotonic()
    exe = build(fmu, "asan")
    print(f"fuzzer {exe} ({time.monotonic() - t0:.1f} s to build or find)", flush=True)
    res = fuzz(fmu, args.target, sequences=args.sequences, seed=args.seed, seconds=args.seconds,
               call_limit=args.call_limit, keep_going=not args.stop_first)
    print(res.report(max_kinds=100))
    return 1 if res.findings else 0


def add_parser(sub):
    f = sub.add_parser("fuzz", help="sanitizer fuzzing of an FMU's C (random fmi2 call sequences)")
    f.add_argument("target", help="a shipped scene name (build/<scene>.fmu) or a .fmu file")
    f.add_argument("--sequences", type=int, default=None, help="number of sequences (default 1000, or unlimited "
                   "with --seconds)")
    f.add_argument("--seed", type=int, default=1, help="sequence k uses seed S + k")
    f.add_argument("--seconds", type=float, default=None, help="stop after T seconds of wall time")
    f.add_argument("--call-limit", type=float, default=10.0, help="a call running longer is a finding (s)")
    f.add_argument("--stop-first", action="store_true", help="stop at the first finding")
    f.add_argument("--trace", action="store_true", help="print every call, status and message (replay a seed)")
    f.add_argument("--build", default=str(REPO_ROOT / "build"))
    return f


if __name__ == "__main__":
    ap = argparse.ArgumentParser(prog="python -m cedra.fmu.fuzz")
    add_parser(ap.add_subparsers(dest="cmd", required=True))
    sys.exit(main(ap.parse_args()))
