"""The run summary as JSON, and other text files of a run (a written deck), each written
atomically (temporary name, then rename)."""
import json
import os

import numpy as np

from pardem.errors import OutputError


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
    """Write ``data`` as JSON to ``path`` atomically; ``OutputError`` (one line naming the file) if
    the file system refuses (disk full, permission), the temporary file removed."""
    _atomic(path, lambda fh: (json.dump(_plain(data), fh, indent=2, allow_nan=False), fh.write("\n")))


def write_text(path, text):
    """Write ``text`` to ``path`` atomically (a deck the calibration wrote, ...); ``OutputError``
    as ``write_json``."""
    _atomic(path, lambda fh: fh.write(text))


def _atomic(path, fill):
    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w") as fh:
            fill(fh)
        os.replace(tmp, path)
    except OSError as err:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise OutputError(f"cannot write {path}: {err.strerror or err}") from None
