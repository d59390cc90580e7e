# The Python package's tests (pytest): run by ctest as `python_tests` with PYTHONPATH=build/python
# (tests/CMakeLists.txt), or by hand: PYTHONPATH=build/python /usr/bin/python3 -m pytest tests/python
import os
import pathlib

import pytest


@pytest.fixture(scope="session")
def reference_dir():
    """TOPOS_REFERENCE_DIR (the shared reference data); the test is skipped, saying so, without."""
    d = os.environ.get("TOPOS_REFERENCE_DIR")
    if not d:
        pytest.skip("TOPOS_REFERENCE_DIR is not set (the reference data: golden cases, checkpoints)")
    return pathlib.Path(d)


def pytest_report_header(config):
    import topos

    return f"topos {topos.__version__} from {pathlib.Path(topos.__file__).parent}"


@pytest.fixture(scope="session")
def datasets_dir():
    """TOPOS_DATASETS_DIR (the raw benchmark datasets); the test is skipped, saying so, without."""
    d = os.environ.get("TOPOS_DATASETS_DIR")
    if not d:
        pytest.skip("TOPOS_DATASETS_DIR is not set (the raw datasets: tu/, topobench/reproduce-hparams.txt)")
    return pathlib.Path(d)
