import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.dirname(os.path.dirname(HERE))
BIN = os.environ.get("SKYLOOP_BIN", os.path.join(SOURCE, "build", "skyloop"))
sys.path.insert(0, os.path.join(SOURCE, "examples"))


def pytest_terminal_summary(terminalreporter):
    """One line when the real learning libraries are absent (their tests are then skipped)."""
    import importlib.util
    missing = [m for m in ("pettingzoo", "gymnasium") if importlib.util.find_spec(m) is None]
    if missing:
        terminalreporter.write_line(f"skipped: the tests against {' and '.join(missing)} (not installed: run "
                                    f"scripts/install-python-env, which needs PyPI)")


@pytest.fixture(scope="session")
def skyloop_bin():
    if not os.path.exists(BIN):
        pytest.skip(f"no skyloop binary at {BIN}")
    return BIN


@pytest.fixture(scope="session")
def source_dir():
    return SOURCE


# A 120 m square (7 x 7 cells, three UAVs from a generated layout): the exact optimum in a fraction
# of a second where the paper's 200 m square takes several, for the tests that solve it.
SQUARE = {"scenario.area_x_m": 120, "scenario.area_y_m": 120, "trajectory.layout": "generated", "env.oracle": "zf"}
SQUARE_SET = [a for k, v in SQUARE.items() for a in ("--set", f"{k}={v}")]


def run_cli(*args, cwd=None):
    r = subprocess.run([BIN, *args], capture_output=True, text=True, cwd=cwd)
    return r
