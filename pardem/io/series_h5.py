"""Time series of the measured quantities as HDF5 (rank 0 writes; one row per sample).

The same columns as the CSV series (by default compress's ``SERIES_COLUMNS``; other drivers pass
their own ``columns``, ``units``, ``row`` and ``description``): one resizable 1-D dataset per column at the
file root, ``step`` (and compress's ``bonds_*``, or the given ``int_columns``) as int64 and the others as float64, each with a ``units`` attribute. The file
attributes ``columns`` (the column order) and ``description`` say what the file holds. Rows are
appended as they come and the file is flushed after each one, so a crash keeps the rows written.

Written with h5py's default (serial) driver by one process: plain h5py reads it, e.g.
``h5py.File("series.h5")["force_fixed"][:]``.
"""
import h5py
import numpy as np

from pardem.io.series import SERIES_COLUMNS, SERIES_UNITS, sample_row

DESCRIPTION = ("pardem time series: one row per sample of the plate displacement, the global plate "
               "forces (compression positive) and the least-squares strain tensor of the elements away "
               "from the plates (compression negative); one dataset per column, in the order of the "
               "'columns' attribute, with its unit in the dataset's 'units' attribute")
CHUNK_ROWS = 1024


def _dtype(column, int_columns=None):
    if int_columns is not None:
        return np.int64 if column in int_columns else np.float64
    return np.int64 if column == "step" or column.startswith("bonds_") else np.float64


class SeriesH5:
    """HDF5 series file; ``append`` writes and flushes one row (so a crash keeps rows).

    ``samples``: ``Reducer.sample`` dicts written first (a restart rewrites the rows it kept).
    The file at ``path`` is replaced. ``columns``, ``units`` (one per column), ``row`` (``row(sample)
    -> values`` in the columns' order), ``description`` and ``int_columns`` (the int64 columns;
    default ``step`` and ``bonds_*``) default to compress's series.
    """

    def __init__(self, path, samples=(), columns=SERIES_COLUMNS, units=SERIES_UNITS, row=sample_row,
                 description=DESCRIPTION, int_columns=None):
        if len(columns) != len(units):
            raise ValueError(f"{len(columns)} columns but {len(units)} units")
        self.path = path
        self.row = row
        self._f = h5py.File(path, "w")
        try:
            self._f.attrs["columns"] = list(columns)
            self._f.attrs["description"] = description
            self._ds = []
            for name, unit in zip(columns, units):
                ds = self._f.create_dataset(name, shape=(0,), maxshape=(None,),
                                            dtype=_dtype(name, int_columns), chunks=(CHUNK_ROWS,))
                ds.attrs["units"] = unit
                self._ds.append(ds)
            self.n_rows = 0
            self._write([row(s) for s in samples])
        except BaseException:
            self._f.close()
            raise

    def append(self, sample):
        self._write([self.row(sample)])

    def _write(self, rows):
        if not rows:
            self._f.flush()
            return
        n0, n1 = self.n_rows, self.n_rows + len(rows)
        for k, ds in enumerate(self._ds):
            ds.resize((n1,))
            ds[n0:n1] = np.array([r[k] for r in rows], dtype=ds.dtype)
        self.n_rows = n1
        self._f.flush()

    def close(self):
        if self._f.id.valid:
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_series_h5(path):
    """Columns of a series HDF5 file as a dict of numpy arrays, in the file's column order.

    Columns are cut to the shortest one, in case a crash struck between two columns of a row.
    """
    with h5py.File(path, "r") as f:
        columns = [str(c) for c in f.attrs.get("columns", SERIES_COLUMNS)]
        data = {c: f[c][()] for c in columns}
    n = min((len(v) for v in data.values()), default=0)
    return {c: v[:n] for c, v in data.items()}
