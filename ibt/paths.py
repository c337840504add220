"""Where the artifact's committed data and figures live (overridable for tests)."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(os.environ.get("IBT_ROOT", Path(__file__).resolve().parent.parent))
DATA_DIR = ROOT / "data"
FIGURES_DIR = ROOT / "figures"
PAPER_DIR = ROOT / "paper"
