"""The run summary as JSON, and other text files of a run (a written deck), each written
atomically (temporary name, then rename)."""
import json
import os

import numpy as np


def _plain(obj):
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, (np.floating, np.integer)):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None      # strict JSON has no NaN: "not defined" (e.g. no analytic modulus)
    return obj


def write_json(path, data):
    tmp = f"{path}.tmp"
    with open(tmp, "w") as fh:
        json.dump(_plain(data), fh, indent=2, allow_nan=False)
        fh.write("\n")
    os.replace(tmp, path)


def write_text(path, text):
    """Write ``text`` to ``path`` atomically (a deck the calibration wrote, ...)."""
    tmp = f"{path}.tmp"
    with open(tmp, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)
