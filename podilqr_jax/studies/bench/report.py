"""How the standalone benchmark modules hand back a report: JSON on stdout, and in a file."""

from __future__ import annotations

import json
import os
from typing import Any, Optional


def emit(report: dict[str, Any], out: Optional[str]) -> None:
    """Print ``report`` as JSON and, with ``out``, write it there too (folders made as needed)."""
    text = json.dumps(report, indent=2)
    if out:
        os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
        with open(out, "w") as f:
            f.write(text + "\n")
    print(text)
