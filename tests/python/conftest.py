# The Python package's tests (pytest): run by ctest as `python_tests` with PYTHONPATH=build/python
# (tests/CMakeLists.txt), or by hand: PYTHONPATH=build/python /usr/bin/python3 -m pytest tests/python
import os
import pathlib

import pytest


def _env_dir(var, what):
    d = os.environ.get(var)
    if not d:
        pytest.skip(f"{var} is not set ({what})")
    return pathlib.Path(d)


@pytest.fixture(scope="session")
def reference_dir():
    """TOPOS_REFERENCE_DIR (the shared reference data); the test is skipped, saying so, without."""
    return _env_dir("TOPOS_REFERENCE_DIR", "the reference data: golden cases, checkpoints")


@pytest.fixture(scope="session")
def datasets_dir():
    """TOPOS_DATASETS_DIR (the raw benchmark datasets); the test is skipped, saying so, without."""
    return _env_dir("TOPOS_DATASETS_DIR", "the raw datasets: tu/, topobench/reproduce-hparams.txt")


def pytest_report_header(config):
    import topos

    return f"topos {topos.__version__} from {pathlib.Path(topos.__file__).parent}"
