"""Time series of the measured quantities as CSV (rank 0 writes; one row per sample).

The default columns are compress's (``SERIES_COLUMNS``, rows from ``Reducer.sample`` dicts); other
drivers pass their own ``columns`` and ``row`` (e.g. ``dict_row(columns)`` for samples that are
dicts keyed by column).

The header names each column with its unit, ``name [unit]`` (e.g. ``time [s]``, ``force_fixed
[N]``), as the HDF5 series' ``units`` attributes; a dimensionless column (unit ``1``) or one written
without units is its bare name. ``read_series`` and ``read_series_rows`` key the columns by bare
name (``column_name``), so a reader need not know the units.

A restarted driver rewrites its series files from the rows its checkpoint kept and then appends
its own: the last run's files are the whole run's series, equal to an uninterrupted run's.
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


def header(columns, units=None):
    """The CSV header of ``columns`` with ``units`` (one per column; None: none): ``name [unit]``,
    the bare name for a dimensionless column (unit ``1`` or empty)."""
    if units is None:
        return list(columns)
    if len(units) != len(columns):
        raise ValueError(f"{len(columns)} columns but {len(units)} units")
    return [c if u in ("1", "") else f"{c} [{u}]" for c, u in zip(columns, units)]


def column_name(text):
    """The bare column name of a header entry ``name [unit]`` (or ``name``)."""
    return text.split(" [", 1)[0].strip()


class SeriesCSV:
    """CSV file with a header line; ``append`` writes one row at once (so a crash keeps rows).

    columns: the column names; row: ``row(sample) -> values`` in the columns' order (default:
    compress's columns of a ``Reducer.sample`` dict); units: one per column for the header
    (``header``; default compress's ``SERIES_UNITS`` with its default columns, else none). Floats
    are written with ``repr`` (they read back exactly). A failed write (disk full, permission)
    raises ``OutputError`` naming the file; the file then holds the rows written before (the last
    one possibly cut) and takes no more.
    """

    def __init__(self, path, columns=SERIES_COLUMNS, row=sample_row, units=None):
        self.path = path
        self.columns, self.row = tuple(columns), row
        if units is None and self.columns == SERIES_COLUMNS:
            units = SERIES_UNITS
        names = header(self.columns, units)
        self.failed = False
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as err:
            raise _output_error(path, err) from None
        self._write([names])

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


def read_series_rows(path):
    """The rows of a series CSV as dicts ``{bare column name: text}`` (units dropped from the
    header, values as written)."""
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        names = [column_name(h) for h in next(reader)]
        return [dict(zip(names, r)) for r in reader]


def read_series(path, columns=SERIES_COLUMNS):
    """Columns of a series CSV as a dict of float lists, keyed by bare name (for tests and
    post-processing); ``columns=None``: every column of the file's header, in its order."""
    with open(path, newline="") as fh:
        names = [column_name(h) for h in next(csv.reader(fh))]
    rows = read_series_rows(path)
    return {k: [float(r[k]) for r in rows] for k in (names if columns is None else columns)}
