"""No memory lost: instantiate / setup / initialize / step / get, serialize, deserialize, set, free state / free
cycles, with the failure paths (each of fmi2Instantiate's allocations failing in turn, a refused GUID,
out-of-memory in fmi2GetFMUstate and fmi2DeSerializeFMUstate, instances freed in every phase), in the fuzzer's
leak mode (tools/fuzz/fmu_fuzz.c --cycles N): under LeakSanitizer (the ASan build), and under valgrind's memcheck
(a plain -O1 -g build) when valgrind is installed. A planted leak shows both checks can fail.

Which builds (each FMU compile costs CI minutes, the generated model of hills3d most): LeakSanitizer on the ASan
builds the fuzz tests compile anyway (bump2d, flat3d); valgrind on the plain hills3d build the thread test uses
too, which adds the heightmap's allocations and valgrind's uninitialized-value checks."""
from __future__ import annotations

import re
import shutil

import pytest

from cedra.fmu import fuzz

SCENES = ["bump2d", "flat3d"]


@pytest.mark.parametrize("scene", SCENES)
def test_no_leak_under_leaksanitizer(scene):
    p = fuzz.run_mode(fuzz.resolve_fmu(scene), ["--cycles", "200"], env={"ASAN_OPTIONS": "detect_leaks=1"})
    assert p.returncode == 0 and "CYCLES done n=200" in p.stdout, p.stdout + p.stderr[-3000:]
    assert "LeakSanitizer" not in p.stderr and "ERROR" not in p.stderr, p.stderr[-3000:]


def test_planted_leak_is_found_by_leaksanitizer():
    p = fuzz.run_mode(fuzz.resolve_fmu("bump2d"), ["--cycles", "3"], defines=("FUZZ_PLANT_LEAK",),
                      env={"ASAN_OPTIONS": "detect_leaks=1"})
    assert p.returncode != 0 and "ERROR: LeakSanitizer: detected memory leaks" in p.stderr, p.stderr[-3000:]
    assert "fmi2DeSerializeFMUstate" in p.stderr
    assert re.search(r"SUMMARY: AddressSanitizer: \d+ byte\(s\) leaked in 3 allocation", p.stderr), p.stderr[-500:]


VALGRIND = shutil.which("valgrind")
needs_valgrind = pytest.mark.skipif(VALGRIND is None, reason="valgrind is not installed: the LeakSanitizer tests "
                                    "above still check for leaks, only the valgrind run is skipped")


def valgrind(scene, cycles, defines=()):
    return fuzz.run_mode(fuzz.resolve_fmu(scene), ["--cycles", str(cycles)], variant="plain", defines=defines,
                         wrapper=[VALGRIND, "--leak-check=full", "--error-exitcode=3"])


@needs_valgrind
def test_no_leak_and_no_error_under_valgrind():
    p = valgrind("hills3d", 6)
    assert p.returncode == 0 and "CYCLES done n=6" in p.stdout, p.stdout + p.stderr[-3000:]
    assert "ERROR SUMMARY: 0 errors" in p.stderr, p.stderr[-3000:]
    assert "All heap blocks were freed -- no leaks are possible" in p.stderr or \
        "definitely lost: 0 bytes" in p.stderr, p.stderr[-3000:]


@needs_valgrind
def test_planted_leak_is_found_by_valgrind():
    p = valgrind("hills3d", 2, defines=("FUZZ_PLANT_LEAK",))
    assert p.returncode == 3, p.stderr[-3000:]
    # one planted block per cycle; valgrind calls a block "possibly lost" when a pointer into it is still lying
    # around (seen once in a loaded full run: 1 definitely + 1 possibly lost), so the two counts together
    lost = {kind: re.search(rf"{kind} lost: ([\d,]+) bytes in ([\d,]+) blocks", p.stderr)
            for kind in ("definitely", "possibly")}
    assert lost["definitely"] and int(lost["definitely"].group(1).replace(",", "")) > 0, p.stderr[-3000:]
    blocks = sum(int(m.group(2).replace(",", "")) for m in lost.values() if m)
    assert blocks == 2, p.stderr[-3000:]
