"""Shared pytest settings: fixed threads and seeds so the suite is deterministic and light."""

from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "tests" / "fixtures"


@pytest.fixture(autouse=True)
def _seeded():
    torch.manual_seed(0)
    yield
