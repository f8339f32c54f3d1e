#!/usr/bin/env bash
# ./build.sh         set up .venv (if missing), generate, compile and package every shipped scene into build/
#                    (pip installs requirements.txt and the package with its 'bench' extra: mujoco, for the benchmark);
#                    an FMU whose stamp matches today's sources is kept, and every compiled object comes from the
#                    object cache (~/.cache/cedra, or CEDRA_CACHE) when its C is unchanged
# ./build.sh demo    set up .venv, build what the main job needs (bump2d), run it: the paper's bump run
#                    (out/bump2d/: CSV, plots; prints timing)
# ./build.sh test    build every shipped scene, check every FMU in build/ (python -m cedra check), then run the
#                    tests (the 15 slowest named at the end); fails when either fails
# Each build writes build/build-report.md (what was built, from the cache or compiled, and how long it took).
# ./build.sh docs    set up .venv, then build the documentation site into build/docs/ (Sphinx, warnings are errors;
#                    docs/conf.py generates the FMU reference from the variable table; no FMU is built)
set -euo pipefail
cd "$(dirname "$0")"
export CEDRA_BUILD_START="${CEDRA_BUILD_START:-$(date +%s.%N)}"     # the build report's "since ./build.sh started"
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
    .venv/bin/pip install -q --upgrade pip
fi
if ! .venv/bin/pip install -q --disable-pip-version-check -r requirements.txt -e '.[bench]' >/tmp/cedra-pip.log 2>&1; then
    cat /tmp/cedra-pip.log; exit 1
fi
PY=.venv/bin/python
if [ "${1:-}" = docs ]; then
    exec $PY -m sphinx -W --keep-going -n -q -b html docs build/docs
fi
case "${1:-}" in
    demo) $PY -m cedra build bump2d --out build
          $PY -m cedra simulate bump2d --build build --out out ;;
    test) shift; $PY -m cedra build --out build
          # every shipped FMU through every checker, one verdict line each (the tests do not run them again)
          check=0; $PY -m cedra check build/*.fmu || check=$?
          $PY -m pytest -q -n 2 --durations=15 "$@"
          [ "$check" = 0 ] || { echo "cedra check failed (exit status $check): see its verdict lines above" >&2; exit 1; } ;;
    "") $PY -m cedra build --out build ;;
    *) echo "usage: $0 [demo|test|docs]" >&2; exit 2 ;;
esac
