"""Folders the tests read: the repository's root, its bundled configs and the tests' own data."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
TEST_DATA = ROOT / "tests" / "data"
SUPPORT = Path(__file__).resolve().parent
