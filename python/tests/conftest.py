import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.dirname(os.path.dirname(HERE))
BIN = os.environ.get("SKYLOOP_BIN", os.path.join(SOURCE, "build", "skyloop"))
sys.path.insert(0, os.path.join(SOURCE, "examples"))


@pytest.fixture(scope="session")
def skyloop_bin():
    if not os.path.exists(BIN):
        pytest.skip(f"no skyloop binary at {BIN}")
    return BIN


@pytest.fixture(scope="session")
def source_dir():
    return SOURCE


def run_cli(*args, cwd=None):
    r = subprocess.run([BIN, *args], capture_output=True, text=True, cwd=cwd)
    return r
