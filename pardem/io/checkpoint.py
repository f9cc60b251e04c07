"""Checkpoints: one HDF5 file per checkpoint, written by all ranks, read on any number of ranks.

Layout (``LAYOUT_VERSION`` 1), readable with plain h5py::

    /elements/<name>   [N, ...]  one row per element, in blocks by writing rank (each rank's owned
                                 rows at the offset given by an exclusive scan of the counts)
        x, v, w [m, m/s, rad/s], q (w, x, y, z body -> world), f, t (forces and torques of the last
        step [N, N m]), radius [m], mass [kg], inertia [kg m^2], x0 (reference of the strain fit
        [m]), x_build (positions at the last ghost rebuild [m]), gid, flags; wall_h [N, n_walls, 3]
        (tangential force of each frictional wall on the element [N]; only with wall friction)
    /bonds/<name>      [B, ...]  each bond once (written by the owner of its lower-gid end)
        gid, gid_i, gid_j, L0 [m], ka [N/m], kb [N m^2], kt [N m/rad], tau_a, tau_b, tau_t [s],
        u1, p1, u2, p2 (body-frame bond axis and twist reference of each end), young [Pa], radius [m]
    /contacts/<name>   [C, ...]  (contact runs) each rank's contact list in its order, in blocks by
                                 rank (``contacts_counts`` [n_ranks]): gid_i, gid_j, shifts (int8
                                 periodic image of j), history (tangential force on i [N]); a pair
                                 with a ghost end appears in the blocks of both ranks
    /series/<column>   [S]       the reducer's samples so far (see pardem.io.series)
    attributes of /: layout_version, pardem_version, complete (1 once fully written), step, time [s],
        plate_positions [m] and plate_velocities [m/s] along the loading axis (fixed, moving),
        n_ranks, owned_counts [n_ranks], n_elements, n_bonds, rng_state (JSON; pardem's physics draws
        no random numbers yet, so {"generator": null}), deck (JSON of the checked deck), constants (JSON: dt,
        plate motion and the other derived run constants), slab_cut_s, slab_cut_g, slab_axis

Writing is atomic: the file is written as ``<name>.tmp``, flushed, marked ``complete = 1``, synced
to disk, then renamed. A run killed during a write leaves the previous checkpoint intact and a
``.tmp`` file that nothing reads. With parallel h5py (``driver="mpio"``) all ranks write their blocks
collectively; without it the ranks take turns writing the same file.
"""
import json
import os
import time

import h5py
import numpy as np

import pardem

LAYOUT_VERSION = 1
ELEMENT_DATASETS = ("x", "v", "w", "q", "f", "t", "radius", "mass", "inertia", "x0", "x_build",
                    "gid", "flags")
BOND_DATASETS = ("gid", "gid_i", "gid_j", "L0", "ka", "kb", "kt", "tau_a", "tau_b", "tau_t",
                 "u1", "p1", "u2", "p2", "young", "radius", "state", "f_tensile", "f_shear", "f_yield",
                 "plastic")
# Bond datasets that checkpoints written before rupture and densification existed lack (their bonds
# are read back intact, unbreakable and elastic).
BOND_OPTIONAL = ("state", "f_tensile", "f_shear", "f_yield", "plastic")
CONTACT_DATASETS = ("gid_i", "gid_j", "shifts", "history")
_CHUNK = 1 << 20   # rows read at once when selecting rows


class CheckpointError(ValueError):
    """A checkpoint cannot be used: missing, truncated, corrupt, incomplete or incompatible."""


def parallel_hdf5(mode="auto"):
    """Whether to write collectively through MPI-IO: ``mode`` is "auto", "mpio" or "serial"."""
    if mode == "serial" or os.environ.get("PARDEM_H5_SERIAL") == "1":
        return False
    has = bool(h5py.get_config().mpi)
    if mode == "mpio" and not has:
        raise CheckpointError("checkpoint.driver = \"mpio\" but this h5py is built without MPI")
    return has


def _json(obj):
    return json.dumps(obj, sort_keys=True, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def write_checkpoint(path, comm, groups, series, attrs, mode="auto"):
    """Write one checkpoint file collectively (every rank calls it with its own rows).

    groups : {"elements": {name: local rows}, "bonds": {...}}, the rows this rank writes.
    series : {column: array} written as is by rank 0 (other ranks may pass the same or None).
    attrs : root attributes (same on every rank); dicts and lists are stored as JSON text.
    """
    tmp = f"{path}.tmp"
    layout = {}
    for gname, arrays in groups.items():
        n_local = len(next(iter(arrays.values())))
        counts = np.array(comm.allgather(n_local), dtype=np.int64)
        layout[gname] = (int(counts[:comm.rank].sum()), n_local, int(counts.sum()), counts)
    series = comm.bcast(series if comm.is_root else None)
    all_attrs = {**attrs, "layout_version": LAYOUT_VERSION, "pardem_version": pardem.__version__,
                 "n_ranks": comm.size, "owned_counts": layout["elements"][3],
                 "n_elements": layout["elements"][2], "n_bonds": layout["bonds"][2], "complete": 0}
    for gname, (_, _, total, counts) in layout.items():   # other groups: rows per writing rank
        if gname not in ("elements", "bonds"):
            all_attrs[f"{gname}_counts"] = counts

    def create(f):
        for k, v in all_attrs.items():
            f.attrs[k] = _json(v) if isinstance(v, (dict, list, tuple)) else v
        for gname, arrays in groups.items():
            g = f.create_group(gname)
            total = layout[gname][2]
            for name, a in arrays.items():
                g.create_dataset(name, shape=(total,) + a.shape[1:], dtype=a.dtype)
        g = f.create_group("series")
        for name, a in series.items():
            g.create_dataset(name, data=np.asarray(a)) if not parallel else \
                g.create_dataset(name, shape=np.shape(a), dtype=np.asarray(a).dtype)

    def fill(f, collective):
        for gname, arrays in groups.items():
            off, n, total, _ = layout[gname]
            if total == 0:   # nothing anywhere: an empty dataset has no storage to write to
                continue
            for name, a in arrays.items():
                ds = f[gname][name]
                if collective:
                    with ds.collective:
                        if n:
                            ds[off:off + n] = a
                        else:
                            _write_nothing(ds, a)
                elif n:
                    ds[off:off + n] = a

    parallel = comm.size > 1 and parallel_hdf5(mode)
    # PARDEM_CHECKPOINT_PAUSE=seconds holds the write between data and completion mark, so that a
    # test can kill the run in the middle of a write
    pause = float(os.environ.get("PARDEM_CHECKPOINT_PAUSE", "0"))
    if parallel:
        with h5py.File(tmp, "w", driver="mpio", comm=comm.comm) as f:
            create(f)
            fill(f, collective=True)
            if comm.is_root:
                for name, a in series.items():
                    f["series"][name][...] = np.asarray(a)
            f.flush()
            time.sleep(pause)
            f.attrs["complete"] = 1
    else:
        if comm.is_root:
            with h5py.File(tmp, "w") as f:
                create(f)
        for r in range(comm.size):        # ranks take turns with the default (serial) driver
            comm.barrier()
            if comm.rank == r:
                with h5py.File(tmp, "r+") as f:
                    fill(f, collective=False)
        comm.barrier()
        time.sleep(pause)
        if comm.is_root:
            with h5py.File(tmp, "r+") as f:
                f.flush()
                f.attrs["complete"] = 1
    comm.barrier()
    if comm.is_root:
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        dfd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    comm.barrier()


def _write_nothing(ds, a):
    """Take part in a collective write with an empty selection (inside ``ds.collective``).

    h5py skips the HDF5 call for an empty slice, which would leave the other ranks waiting in the
    collective write forever: a rank with no rows must still make the call.
    """
    shape = (1,) + tuple(a.shape[1:])
    file_space = ds.id.get_space()
    file_space.select_none()
    mem_space = h5py.h5s.create_simple(shape)
    mem_space.select_none()
    ds.id.write(mem_space, file_space, np.zeros(shape, dtype=ds.dtype), dxpl=ds._dxpl)


def inspect(path):
    """Validate a checkpoint and return its root attributes (JSON fields decoded).

    Raises CheckpointError for a missing, unreadable, truncated, incomplete or foreign file.
    """
    if not os.path.exists(path):
        raise CheckpointError(f"--restart {path}: no such file")
    try:
        with h5py.File(path, "r") as f:
            attrs = {k: f.attrs[k] for k in f.attrs}
            version = attrs.get("layout_version")
            if version != LAYOUT_VERSION:
                raise CheckpointError(
                    f"--restart {path}: checkpoint layout version {version if version is None else int(version)}, "
                    f"this pardem reads version {LAYOUT_VERSION}")
            if int(attrs.get("complete", 0)) != 1:
                raise CheckpointError(f"--restart {path}: the checkpoint is incomplete (its write was interrupted)")
            groups = [("elements", ELEMENT_DATASETS, attrs["n_elements"]),
                      ("bonds", BOND_DATASETS, attrs["n_bonds"])]
            if "contacts" in f:
                groups.append(("contacts", CONTACT_DATASETS, int(np.sum(attrs["contacts_counts"]))))
            for gname, names, n in groups:
                for name in names:
                    if gname == "bonds" and name in BOND_OPTIONAL and f"{gname}/{name}" not in f:
                        continue
                    if f"{gname}/{name}" not in f:
                        raise CheckpointError(f"--restart {path}: dataset /{gname}/{name} is missing")
                    if f[gname][name].shape[0] != n:
                        raise CheckpointError(f"--restart {path}: /{gname}/{name} has {f[gname][name].shape[0]} "
                                              f"rows, expected {n}")
                    f[gname][name][-1:]      # reading the last row detects a truncated file
            series = {k: f["series"][k][...] for k in f["series"]}
    except CheckpointError:
        raise
    except (OSError, KeyError, ValueError) as err:
        raise CheckpointError(f"--restart {path}: not a readable pardem checkpoint ({err})") from None
    for k in ("deck", "constants", "rng_state"):
        attrs[k] = json.loads(attrs[k])
    attrs["series"] = series
    return attrs


def has_dataset(path, name):
    """True when the checkpoint holds dataset ``name`` (e.g. the optional ``elements/wall_h``)."""
    with h5py.File(path, "r") as f:
        return name in f


def bond_datasets(path):
    """The bond datasets held by checkpoint ``path`` (``BOND_DATASETS`` less missing optional ones)."""
    with h5py.File(path, "r") as f:
        return [n for n in BOND_DATASETS if n not in BOND_OPTIONAL or f"bonds/{n}" in f]


def read_rows(path, group, names, select):
    """Rows of ``/group/<names>`` chosen by ``select``: a slice, or ``(keys, fn)`` where ``fn`` maps
    a dict of chunks of the ``keys`` columns to a boolean mask of the rows wanted.

    Returns {name: array}. The keys are scanned in chunks; each dataset is then read once over the
    range spanning the wanted rows.
    """
    with h5py.File(path, "r") as f:
        g = f[group]
        if isinstance(select, slice):
            return {n: g[n][select] for n in names}
        keys, fn = select
        total = g[names[0]].shape[0]
        mask = np.zeros(total, dtype=bool)
        for start in range(0, total, _CHUNK):
            stop = min(start + _CHUNK, total)
            mask[start:stop] = fn({k: g[k][start:stop] for k in keys})
        idx = np.nonzero(mask)[0]
        if len(idx) == 0:
            return {n: np.zeros((0,) + g[n].shape[1:], g[n].dtype) for n in names}
        lo, hi = idx[0], idx[-1] + 1
        sub = mask[lo:hi]
        everything = bool(sub.all())
        return {n: g[n][lo:hi] if everything else g[n][lo:hi][sub] for n in names}


def checkpoint_name(step):
    return f"checkpoint-{step:010d}.h5"


def prune(paths, keep):
    """Delete all but the last ``keep`` of ``paths`` (this run's checkpoints, oldest first; rank 0
    only); returns the kept paths. Files of other runs in the same directory are left alone."""
    for path in paths[:-keep] if keep > 0 else []:
        if os.path.exists(path):
            os.remove(path)
    return list(paths[-keep:]) if keep > 0 else list(paths)
