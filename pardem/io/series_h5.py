"""Time series of the measured quantities as HDF5 (rank 0 writes; one row per sample).

The same columns as the CSV series (by default compress's ``SERIES_COLUMNS``; other drivers pass
their own ``columns``, ``units``, ``row`` and ``description``): one resizable 1-D dataset per column at the
file root, ``step`` (and compress's ``bonds_*``, or the given ``int_columns``) as int64 and the others as float64, each with a ``units`` attribute. The file
attributes ``columns`` (the column order) and ``description`` say what the file holds.

Rows are buffered in memory and written together (one resize and one write per column, then an
HDF5 flush) every ``flush_rows`` rows or when ``flush_seconds`` have passed since the last flush
(checked at each row), at ``flush()`` and at ``close()`` (also when the writer is garbage-collected
or the interpreter exits normally). A hard crash (SIGKILL, ``os._exit``, an ``MPI_Abort`` from
another rank) therefore loses at most the rows appended since the last flush: fewer than
``flush_rows`` rows, or ``flush_seconds`` of them. The file on disk always holds a prefix of the
rows appended. A full disk or a denied write raises ``OutputError`` (one line naming the file)
before HDF5 writes anything (the space a flush needs is held first), and the writer writes no more;
the file keeps the rows flushed before and closes cleanly. A restarted run does not read this file: it rewrites it from the rows its checkpoint
kept (``samples``).

Written with h5py's default (serial) driver by one process: plain h5py reads it, e.g.
``h5py.File("series.h5")["force_fixed"][:]``.
"""
import os
import re
import time
import weakref

import h5py
import numpy as np

from pardem.errors import OutputError
from pardem.io.checkpoint import hold_space, release_space
from pardem.io.series import SERIES_COLUMNS, SERIES_UNITS, sample_row

DESCRIPTION = ("pardem time series: one row per sample of the plate displacement, the global plate "
               "forces (compression positive) and the least-squares strain tensor of the elements away "
               "from the plates (compression negative); one dataset per column, in the order of the "
               "'columns' attribute, with its unit in the dataset's 'units' attribute")
CHUNK_ROWS = 1024
FLUSH_ROWS = 100        # rows buffered before a write (a default run samples about 200 rows)
FLUSH_SECONDS = 10.0    # and at most this long [s] between two flushes while rows arrive


def _dtype(column, int_columns=None):
    if int_columns is not None:
        return np.int64 if column in int_columns else np.float64
    return np.int64 if column == "step" or column.startswith("bonds_") else np.float64


class SeriesH5:
    """HDF5 series file; ``append`` buffers one row, written every ``flush_rows`` rows or
    ``flush_seconds`` seconds (see the module docstring for what a crash keeps).

    ``samples``: ``Reducer.sample`` dicts written (and flushed) first: a restart rewrites the rows
    it kept. The file at ``path`` is replaced. ``columns``, ``units`` (one per column), ``row``
    (``row(sample) -> values`` in the columns' order), ``description`` and ``int_columns`` (the
    int64 columns; default ``step`` and ``bonds_*``) default to compress's series.
    ``flush_rows`` >= 1; ``flush_seconds`` >= 0 [s] (0: every row is written and flushed at once).
    ``n_rows``: rows appended so far (written or buffered).
    """

    def __init__(self, path, samples=(), columns=SERIES_COLUMNS, units=SERIES_UNITS, row=sample_row,
                 description=DESCRIPTION, int_columns=None, flush_rows=FLUSH_ROWS, flush_seconds=FLUSH_SECONDS):
        if len(columns) != len(units):
            raise ValueError(f"{len(columns)} columns but {len(units)} units")
        if not (isinstance(flush_rows, (int, np.integer)) and flush_rows >= 1):
            raise ValueError(f"flush_rows must be an integer >= 1, got {flush_rows!r}")
        if not (np.isfinite(flush_seconds) and flush_seconds >= 0.0):
            raise ValueError(f"flush_seconds must be a finite number >= 0 [s], got {flush_seconds!r}")
        self.path = path
        self.row = row
        self.flush_rows, self.flush_seconds = int(flush_rows), float(flush_seconds)
        self._failed = []      # shared with the finalizer: a failed write ends all writing
        try:
            self._f = h5py.File(path, "w")
        except OSError as err:
            raise OutputError(f"cannot write {path}: {_reason(err)}") from None
        try:
            self._f.attrs["columns"] = list(columns)
            self._f.attrs["description"] = description
            self._ds = []
            for name, unit in zip(columns, units):
                ds = self._f.create_dataset(name, shape=(0,), maxshape=(None,),
                                            dtype=_dtype(name, int_columns), chunks=(CHUNK_ROWS,))
                ds.attrs["units"] = unit
                self._ds.append(ds)
            self._pending = [row(s) for s in samples]
            self.n_rows = len(self._pending)
            _write(self._f, self._ds, self._pending, self._failed)
        except BaseException:
            if self._f.id.valid:
                self._f.close()     # a failed write (OutputError) detached it already
            raise
        self._last_flush = time.monotonic()
        # the buffered rows reach the file even when close is never called (no reference to self)
        self._finalizer = weakref.finalize(self, _write_and_close, self._f, self._ds, self._pending,
                                           self._failed)

    def append(self, sample):
        """Buffer one row; write the buffer when it holds ``flush_rows`` rows or the last flush is
        ``flush_seconds`` old."""
        # copies of array values: a buffered row must not change with a caller's array
        self._pending.append([v.copy() if isinstance(v, np.ndarray) else v for v in self.row(sample)])
        self.n_rows += 1
        if len(self._pending) >= self.flush_rows or time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self):
        """Write the buffered rows and flush the file (a checkpoint of the run may call it)."""
        if self._f.id.valid:
            _write(self._f, self._ds, self._pending, self._failed)
        self._last_flush = time.monotonic()

    def close(self):
        """Write the buffered rows and close the file (idempotent)."""
        self._finalizer()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _flush_bytes(n0, n1, datasets):
    """An upper bound of the bytes a flush of rows ``n0`` to ``n1`` adds to the file: per column,
    the chunks these rows start (``CHUNK_ROWS`` rows each, allocated whole when first written)
    and 3 KiB for the chunk index they may grow (a v1 B-tree node of HDF5, 2,096 bytes), plus
    16 KiB for the file's own metadata (object headers, superblock; about 10 KiB for a new file of
    14 columns)."""
    new = -(-n1 // CHUNK_ROWS) - -(-n0 // CHUNK_ROWS)
    per_column = [new * CHUNK_ROWS * ds.dtype.itemsize + (3072 if new else 0) for ds in datasets]
    return sum(per_column) + 16384


def _write(f, datasets, rows, failed):
    """Append ``rows`` (emptied in place) to ``datasets``: one resize and one write per column.

    The disk space the write may take is held in the file first (``checkpoint.hold_space``): a
    full disk or a quota then fails here, before HDF5 writes anything, and the file keeps the
    rows flushed before and still closes (HDF5 1.10 crashed closing a file whose write had
    failed). ``OutputError`` names the file; ``failed`` (a list) records it, and nothing is
    written afterwards."""
    if failed:
        raise OutputError(f"cannot write the series: an earlier write failed ({failed[0]})")
    path = f.filename
    n0 = datasets[0].shape[0] if datasets else 0
    try:
        size = os.path.getsize(path)
        nbytes = size + _flush_bytes(n0, n0 + len(rows), datasets)
        hold_space(path, nbytes)
    except OSError as err:
        failed.append(_reason(err))
        _detach(f)
        raise OutputError(f"cannot write {path}: {failed[0]}") from None
    try:
        if rows:
            n1 = n0 + len(rows)
            for k, ds in enumerate(datasets):
                ds.resize((n1,))
                ds[n0:n1] = np.array([r[k] for r in rows], dtype=ds.dtype)
            rows.clear()
        f.flush()
    except (OSError, RuntimeError) as err:
        # HDF5 failed inside (a file system without fallocate, or more than the bound): its state
        # cannot be flushed or closed again (HDF5 1.10 crashes at the interpreter's exit)
        failed.append(_reason(err))
        _detach(f)
        raise OutputError(f"cannot write {path}: {failed[0]}") from None
    release_space(path, nbytes)


def _reason(err):
    """The OS's reason of an h5py or os error, in one line."""
    text = str(err)
    m = re.search(r"error message = '([^']*)'", text)
    if m:
        return m.group(1)
    return getattr(err, "strerror", None) or (text.splitlines()[0] if text else type(err).__name__)


def _detach(f):
    """Close ``f`` after a failed write: its descriptor is first pointed at /dev/null, so the file
    on disk stays as its last successful flush left it (a consistent file of the rows flushed
    then) and closing it writes nothing there (nor crashes, as closing a file whose write failed
    did)."""
    try:
        fd = f.id.get_vfd_handle()
        null = os.open(os.devnull, os.O_RDWR)
        os.dup2(null, fd)
        os.close(null)
        f.close()
    except Exception:   # noqa: BLE001 - best effort: the write already failed and is reported
        pass


def _write_and_close(f, datasets, rows, failed):
    if f.id.valid and not failed:     # a failed write closed it already (``_detach``)
        try:
            _write(f, datasets, rows, failed)
        finally:
            if f.id.valid:
                f.close()


def read_series_h5(path):
    """Columns of a series HDF5 file as a dict of numpy arrays, in the file's column order.

    Columns are cut to the shortest one, in case a crash struck between two columns of a row.
    """
    with h5py.File(path, "r") as f:
        columns = [str(c) for c in f.attrs.get("columns", SERIES_COLUMNS)]
        data = {c: f[c][()] for c in columns}
    n = min((len(v) for v in data.values()), default=0)
    return {c: v[:n] for c, v in data.items()}
