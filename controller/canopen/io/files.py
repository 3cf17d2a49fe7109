"""Files other programs wait for: strict JSON written to a temporary name, then renamed."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path


def json_safe(obj):
    """``obj`` with every non-finite float (NaN: "no sample yet") as None, so that the JSON
    written is strict (null, not NaN, which JSON does not have)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def write_json_atomic(path: str | Path, data, indent: int | None = 1) -> None:
    """Write ``data`` as strict JSON (:func:`json_safe`) to a temporary name, then rename:
    a script waiting for the file never reads half of it."""
    tmp = Path(f"{path}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(json_safe(data), indent=indent, default=str, allow_nan=False))
    os.replace(tmp, path)
