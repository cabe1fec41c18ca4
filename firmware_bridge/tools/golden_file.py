"""What the golden-frame generators (make_golden.py, make_cia402_golden.py)
share: the exact JSON text of a golden file and the command line that writes
it (``[OUT.json]``, default the committed file)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any


def render(golden: dict[str, Any]) -> str:
    """The exact text of a golden file (sorted keys, so it diffs stably)."""
    return json.dumps(golden, indent=1, sort_keys=True) + "\n"


def write(argv: list[str], default_out: Path, text: str) -> int:
    """Writes ``text`` to ``argv[1]`` (or ``default_out``); the exit status."""
    out = Path(argv[1]) if len(argv) > 1 else default_out
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"wrote {out}", file=sys.stderr)
    return 0
