"""Time series of the measured quantities as CSV (rank 0 writes; one row per sample).

The default columns are compress's (``SERIES_COLUMNS``, rows from ``Reducer.sample`` dicts); other
drivers pass their own ``columns`` and ``row`` (e.g. ``dict_row(columns)`` for samples that are
dicts keyed by column).
"""
import csv

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
    """CSV file with a header line; ``append`` writes and flushes one row (so a crash keeps rows).

    columns: the header; row: ``row(sample) -> values`` in the columns' order (default: compress's
    columns of a ``Reducer.sample`` dict). Floats are written with ``repr`` (they read back exactly).
    """

    def __init__(self, path, columns=SERIES_COLUMNS, row=sample_row):
        self.path = path
        self.columns, self.row = tuple(columns), row
        self._fh = open(path, "w", newline="")
        self._w = csv.writer(self._fh)
        self._w.writerow(self.columns)

    def append(self, sample):
        self._w.writerow([repr(float(v)) if isinstance(v, float) else v for v in self.row(sample)])
        self._fh.flush()

    def close(self):
        self._fh.close()


def read_series(path, columns=SERIES_COLUMNS):
    """Columns of a series CSV as a dict of float lists (for tests and post-processing);
    ``columns=None``: every column of the file's header, in its order."""
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        names = reader.fieldnames if columns is None else columns
    return {k: [float(r[k]) for r in rows] for k in names}
