import os
from pathlib import Path

import pytest

# The dev meshes: $VORO3D_DEV_DATA, else shared/data/dev beside the checkout. Tests take the path
# from the dev_meshes fixture, which skips them when the folder is absent.
DEV_DATA = Path(os.environ.get("VORO3D_DEV_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data" / "dev")
# The real scans (CGAL's example point sets): beside the dev meshes.
SCAN_DATA = DEV_DATA.parent / "scans"


def pytest_addoption(parser):
    parser.addoption("--slow", action="store_true", default=False,
                     help="run the long property-test budget (10,000 extraction cases)")


def pytest_configure(config):
    from hypothesis import HealthCheck, settings

    common = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    # CI replays the same 150 cases every run (a red build must mean a change broke them);
    # --slow searches fresh random cases.
    settings.register_profile("ci", max_examples=150, derandomize=True, **common)
    settings.register_profile("slow", max_examples=2500, **common)
    settings.load_profile("slow" if config.getoption("--slow") else "ci")


@pytest.fixture(scope="session")
def dev_meshes() -> Path:
    """The dev-mesh folder; skips the test when it is absent."""
    if not DEV_DATA.is_dir():
        pytest.skip(f"dev meshes not found at {DEV_DATA}")
    return DEV_DATA


@pytest.fixture(scope="session")
def scans() -> Path:
    """The real-scan folder; skips the test when it is absent."""
    if not SCAN_DATA.is_dir():
        pytest.skip(f"scans not found at {SCAN_DATA}")
    return SCAN_DATA


@pytest.fixture
def gil_free():
    """``gil_free(call)`` runs ``call`` in a thread while this one spins, and returns the call's
    wall time and the longest gap between two spins: a call that holds the GIL stops the spinning
    for about its whole length."""
    import threading
    import time

    def probe(call):
        done = threading.Event()
        worker = threading.Thread(target=lambda: (call(), done.set()))
        start = last = time.perf_counter()
        worker.start()
        longest = 0.0
        while not done.is_set():
            now = time.perf_counter()
            longest, last = max(longest, now - last), now
        worker.join()
        return time.perf_counter() - start, longest

    return probe
