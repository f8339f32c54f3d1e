import sys
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
for _p in (_ROOT / "python", _ROOT / "tests"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))


import pytest  # noqa: E402  (after the path set-up above)

from fmu_harness import Toy, toy_fmu  # noqa: E402


@pytest.fixture(scope="session")
def toy(tmp_path_factory):
    """The toy FMU (tests/toy_model.py), built once per session (per xdist worker)."""
    return toy_fmu(tmp_path_factory)


@pytest.fixture
def inst(toy):
    """One instance of the toy FMU, closed after the test."""
    t = Toy(toy)
    yield t
    t.close()
