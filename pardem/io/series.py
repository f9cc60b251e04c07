"""Time series of the measured quantities as CSV (rank 0 writes; one row per sample).

The default columns are compress's (``SERIES_COLUMNS``, rows from ``Reducer.sample`` dicts); other
drivers pass their own ``columns`` and ``row`` (e.g. ``dict_row(columns)`` for samples that are
dicts keyed by column).
"""
import csv
import io
import os

from pardem.errors import OutputError

SERIES_COLUMNS = ("step", "time", "plate_displacement", "force_fixed", "force_moving",
                  "eps_xx", "eps_yy", "eps_zz", "eps_xy", "eps_xz", "eps_yz",
                  "bonds_broken", "bonds_broken_step", "bonds_yielded")
SERIES_UNITS = ("1", "s", "m", "N", "N", "1", "1", "1", "1", "1", "1", "1", "1", "1")


def sample_row(s):
    """The CSV row of one ``Reducer.sample`` dict."""
    e = s["eps"]
    return (s["step"], s["time"], s["plate_displacement"], s["force_fixed"], s["force_moving"],
            e[0, 0], e[1, 1], e[2, 2], e[0, 1], e[0, 2], e[1, 2],
            s["bonds_broken"], s["bonds_broken_step"], s["bonds_yielded"])


def dict_row(columns):
    """``row`` function of samples that are dicts keyed by the column names."""
    columns = tuple(columns)
    return lambda s: [s[k] for k in columns]


class SeriesCSV:
    """CSV file with a header line; ``append`` writes one row at once (so a crash keeps rows).

    columns: the header; row: ``row(sample) -> values`` in the columns' order (default: compress's
    columns of a ``Reducer.sample`` dict). Floats are written with ``repr`` (they read back exactly).
    A failed write (disk full, permission) raises ``OutputError`` naming the file; the file then
    holds the rows written before (the last one possibly cut) and takes no more.
    """

    def __init__(self, path, columns=SERIES_COLUMNS, row=sample_row):
        self.path = path
        self.columns, self.row = tuple(columns), row
        self.failed = False
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as err:
            raise _output_error(path, err) from None
        self._write([self.columns])

    def append(self, sample):
        self._write([[repr(float(v)) if isinstance(v, float) else v for v in self.row(sample)]])

    def _write(self, rows):
        # rows go to the file descriptor in one write each, with no buffer of Python's that a
        # failed write would leave to be written again at close (and fail again at exit)
        if self.failed:
            raise OutputError(f"cannot write {self.path}: an earlier write failed")
        text = io.StringIO(newline="")
        csv.writer(text).writerows(rows)
        data = text.getvalue().encode()
        try:
            while data:
                data = data[os.write(self._fd, data):]
        except OSError as err:
            self.failed = True
            raise _output_error(self.path, err) from None

    def close(self):
        if getattr(self, "_fd", None) is not None:
            os.close(self._fd)
            self._fd = None

    __del__ = close


def _output_error(path, err):
    """``OutputError`` of a failed write of ``path`` (one line: the file and the OS's reason)."""
    return OutputError(f"cannot write {path}: {err.strerror or err}")


def read_series(path, columns=SERIES_COLUMNS):
    """Columns of a series CSV as a dict of float lists (for tests and post-processing);
    ``columns=None``: every column of the file's header, in its order."""
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        names = reader.fieldnames if columns is None else columns
    return {k: [float(r[k]) for r in rows] for k in names}
