"""Fixtures of the interoperability tests: flowopt against software this
project did not write (Eclipse Cyclone DDS as a ROS 2 participant, the
Python ``mcap`` reader, headless Chromium). The ``flowopt`` binary is
``FLOWOPT_BIN``, else the repository's release build."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def flowopt_bin() -> Path:
    path = Path(os.environ.get("FLOWOPT_BIN", REPO / "target/release/flowopt"))
    if not path.is_file():
        pytest.fail(f"{path} not found: build it with `cargo build --release` or point FLOWOPT_BIN at it", pytrace=False)
    return path


@pytest.fixture
def config() -> Path:
    return REPO / "config/default.toml"


@pytest.fixture
def prefix() -> str:
    """An iceoryx2 service prefix of the test's own."""
    return f"flowopt-interop-{os.getpid()}-{random.randrange(1 << 30)}"


@pytest.fixture
def domain() -> int:
    """A DDS domain of the test's own."""
    return random.randrange(1, 200)
