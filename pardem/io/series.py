"""Time series of the measured quantities as CSV (rank 0 writes; one row per sample)."""
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


class SeriesCSV:
    """CSV file with a header line; ``append`` writes and flushes one row (so a crash keeps rows)."""

    def __init__(self, path):
        self.path = path
        self._fh = open(path, "w", newline="")
        self._w = csv.writer(self._fh)
        self._w.writerow(SERIES_COLUMNS)

    def append(self, sample):
        self._w.writerow([repr(float(v)) if isinstance(v, float) else v for v in sample_row(sample)])
        self._fh.flush()

    def close(self):
        self._fh.close()


def read_series(path):
    """Columns of a series CSV as a dict of float lists (for tests and post-processing)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: [float(r[k]) for r in rows] for k in SERIES_COLUMNS}
