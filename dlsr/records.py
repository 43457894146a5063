"""Results files written one JSON line per finished item, so long runs resume after a kill."""

from __future__ import annotations

import json
import logging
from pathlib import Path

__all__ = ["read_jsonl"]

log = logging.getLogger(__name__)


def read_jsonl(path) -> list[dict]:
    """The JSON objects of a JSON-lines file, in file order.

    Blank lines are ignored; a line that is not a JSON object (typically the last one, cut by
    an interrupted run) is skipped with a warning naming the file and line. A missing file
    reads as no records.
    """
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            rec = None
        if not isinstance(rec, dict):
            log.warning("%s:%d: skipping an incomplete line (an interrupted run?)", path, number)
            continue
        out.append(rec)
    return out
