"""Strict JSON text for everything densecalib writes or prints: other tools (jq, browsers,
ROS parameter loaders) reject Python's NaN/Infinity tokens, so a figure that could not be
measured becomes null, and numpy scalars/arrays become plain numbers and lists."""
from __future__ import annotations

import json
import math

import numpy as np


def jsonable(obj):
    """`obj` with numpy values as Python ones, tuples as lists, keys as strings and every
    non-finite float as None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj, indent: int | None = 2) -> str:
    """`obj` as strict JSON (allow_nan=False after `jsonable`, so a stray NaN fails loudly here
    rather than in the reader)."""
    return json.dumps(jsonable(obj), indent=indent, allow_nan=False)
