"""Folders of the checkout the tests run from (tests are never installed, so their own location is the checkout)."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CELL_PATH = REPO_ROOT / "configs" / "cell.toml"
