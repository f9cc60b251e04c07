"""Checkpoints: one HDF5 file per checkpoint, written by all ranks, read on any number of ranks.

Layout (``LAYOUT_VERSION`` 2), readable with plain h5py::

    /elements/<name>   [N, ...]  one row per element, in blocks by writing rank (each rank's owned
                                 rows at the offset given by an exclusive scan of the counts)
        x, v, w [m, m/s, rad/s], q (w, x, y, z body -> world), f, t (forces and torques of the last
        step [N, N m]), radius [m], mass [kg], inertia [kg m^2], x0 (reference of the strain fit
        [m]), x_build (positions at the last ghost rebuild [m]), gid, flags; wall_h [N, n_walls, 3]
        (tangential force of each frictional wall on the element [N]; only with wall friction);
        property_<name> [N] or [N, k] float64 (a custom per-particle array, ``sim.particles.
        add_property``; any number of them)
    /bonds/<name>      [B, ...]  each bond once (written by the owner of its lower-gid end)
        gid, gid_i, gid_j, L0 [m], ka [N/m], kb [N m^2], kt [N m/rad], tau_a, tau_b, tau_t [s],
        u1, p1, u2, p2 (body-frame bond axis and twist reference of each end), young [Pa], radius [m],
        state, f_tensile, f_shear, f_yield [N], plastic
    /contacts/<name>   [C, ...]  (contact runs) each rank's contact list in its order, in blocks by
                                 rank (``contacts_counts`` [n_ranks]): gid_i, gid_j, shifts (int8
                                 periodic image of j), history (tangential force on i [N]); a pair
                                 with a ghost end appears in the blocks of both ranks
    /series/<column>   [S]       the reducer's samples so far (see pardem.io.series)
    attributes of /: layout_version, pardem_version, complete (1 once fully written), step, time [s],
        plate_positions [m] and plate_velocities [m/s] along the loading axis (fixed, moving),
        n_ranks, owned_counts [n_ranks], n_elements, n_bonds, rng_state (JSON; pardem's physics draws
        no random numbers yet, so {"generator": null}), deck (JSON of the checked deck), constants (JSON: dt,
        plate motion and the other derived run constants), slab_cut_s, slab_cut_g, slab_axis,
        datasets (JSON list of every dataset), attrs_digest (see Integrity)

Integrity (version 2): every dataset carries ``blocks`` (rows of each writer's block, int64) and
``digests`` (SHA-256 of each block, its first 128 bits in hex: its path, dtype, shape and bytes),
computed by the rank that wrote the block; ``attrs_digest`` is the same digest of every root
attribute but ``complete`` (names, dtypes, shapes, values). ``inspect`` recomputes them all and checks the attributes against
the data (counts, dtypes, shapes, gids unique and bond and contact ends existing, step and time,
finite state), so a flipped byte or an edited attribute is refused in one line. (HDF5's Fletcher32
filter was not used: its ones'-complement sums do not see a 16-bit word turned from 0x0000 into
0xFFFF, e.g. a 0.0 overwritten by a NaN of all one bits.) No checkpoint holds a NaN, nor an infinity
outside the bonds' strengths ``f_tensile``, ``f_shear`` (inf: unbreakable): ``write_checkpoint``
refuses such a state with ``InstabilityError``.

Writing is atomic: the file is written as ``<name>.tmp``, flushed, marked ``complete = 1``, synced
to disk, then renamed. A run killed during a write leaves the previous checkpoint intact and a
``.tmp`` file that nothing reads. With parallel h5py (``driver="mpio"``) all ranks write their blocks
collectively; without it the ranks take turns writing the same file. An OS error (disk full,
permission) removes the ``.tmp``, keeps the earlier checkpoints and raises ``OutputError`` on
every rank (``all_ranks``).
"""
import ctypes
import errno
import hashlib
import json
import os
import re
import signal
import time

import h5py
import numpy as np

import pardem
from pardem.config import DeckError
from pardem.errors import InstabilityError, OutputError
from pardem.physics.finite import first_nonfinite

LAYOUT_VERSION = 2
PROPERTY_PREFIX = "property_"   # /elements/property_<name>: a custom per-particle array (Elements.properties)
ELEMENT_DATASETS = ("x", "v", "w", "q", "f", "t", "radius", "mass", "inertia", "x0", "x_build",
                    "gid", "flags")
BOND_DATASETS = ("gid", "gid_i", "gid_j", "L0", "ka", "kb", "kt", "tau_a", "tau_b", "tau_t",
                 "u1", "p1", "u2", "p2", "young", "radius", "state", "f_tensile", "f_shear", "f_yield",
                 "plastic")
# Bond datasets that checkpoints written before rupture and densification existed lack (layout 1;
# such files are refused now, the name stays for the readers' benefit).
BOND_OPTIONAL = ("state", "f_tensile", "f_shear", "f_yield", "plastic")
CONTACT_DATASETS = ("gid_i", "gid_j", "shifts", "history")
_CHUNK = 1 << 20   # rows read at once when selecting rows

_F8, _I8, _U1, _I1 = np.dtype("<f8"), np.dtype("<i8"), np.dtype("u1"), np.dtype("i1")
_VEC, _ANY = (3,), (None,)
# dtype and shape after the row axis of every dataset (None: any length)
SCHEMA = {
    "elements": {**{k: (_F8, _VEC) for k in ("x", "v", "w", "f", "t", "x0", "x_build")},
                 "q": (_F8, (4,)), "radius": (_F8, ()), "mass": (_F8, ()), "inertia": (_F8, ()),
                 "gid": (_I8, ()), "flags": (_U1, ()), "wall_h": (_F8, (None, 3))},
    "bonds": {**{k: (_F8, ()) for k in ("L0", "ka", "kb", "kt", "tau_a", "tau_b", "tau_t", "young",
                                         "radius", "f_tensile", "f_shear", "f_yield", "plastic")},
              **{k: (_I8, ()) for k in ("gid", "gid_i", "gid_j")},
              **{k: (_F8, _VEC) for k in ("u1", "p1", "u2", "p2")}, "state": (_U1, ())},
    "contacts": {"gid_i": (_I8, ()), "gid_j": (_I8, ()), "shifts": (_I1, _VEC), "history": (_F8, _ANY)},
}
REQUIRED = {"elements": ELEMENT_DATASETS, "bonds": BOND_DATASETS, "contacts": CONTACT_DATASETS}
OPTIONAL = {"elements": ("wall_h",)}
# where an infinity means something (an unbreakable bond); a NaN is refused everywhere
ALLOW_INF = {("bonds", "f_tensile"), ("bonds", "f_shear")}
POSITIVE = {("elements", "radius"), ("elements", "mass"), ("elements", "inertia")}
# root attributes checked for finiteness before writing (the others are integers or JSON)
FINITE_ATTRS = ("time", "plate_positions", "plate_velocities")
_INTERNAL = ("complete", "attrs_digest")   # root attributes not covered by attrs_digest


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


def checkpoint_pause():
    """Seconds ``PARDEM_CHECKPOINT_PAUSE`` holds a write between its data and its completion mark
    (tests kill a run in the middle of a write); 0 when unset. DeckError when malformed (drivers
    may call this before any output to refuse it up front)."""
    spec = os.environ.get("PARDEM_CHECKPOINT_PAUSE", "").strip()
    if not spec:
        return 0.0
    try:
        value = float(spec)
    except ValueError:
        value = float("nan")
    if not (0.0 <= value <= 3600.0):
        raise DeckError(f"PARDEM_CHECKPOINT_PAUSE = {spec!r}: expected seconds, a number in [0, 3600]")
    return value


def _json(obj):
    return json.dumps(obj, sort_keys=True, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def block_digest(gname, name, a):
    """SHA-256 (first 128 bits, hex) of one block of rows of dataset ``/gname/name``: its path,
    dtype, shape and bytes (SHA-256: the fastest of hashlib's digests where CPUs have SHA
    instructions, ~1-2 GB/s)."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha256()
    h.update(f"/{gname}/{name}|{a.dtype.str}|{tuple(a.shape)}|".encode())
    h.update(a.reshape(-1).view(np.uint8))
    return h.hexdigest()[:32]


def attrs_digest(attrs):
    """SHA-256 (first 128 bits, hex) of root attributes as h5py reads them (every name but
    ``_INTERNAL``): names, dtypes, shapes and values."""
    h = hashlib.sha256()
    for k in sorted(attrs):
        if k in _INTERNAL:
            continue
        v = attrs[k]
        if isinstance(v, str):
            tag, data = b"s", v.encode("utf-8", "surrogatepass")
        elif isinstance(v, bytes):
            tag, data = b"b", v
        else:
            a = np.asarray(v)
            if a.dtype.kind in "OUS":
                tag, data = b"o", _json([str(x) for x in a.reshape(-1)]).encode() + repr(a.shape).encode()
            else:
                a = np.ascontiguousarray(a)
                tag = b"a" + a.dtype.str.encode() + repr(a.shape).encode()
                data = a.reshape(-1).view(np.uint8).tobytes()
        key = k.encode("utf-8", "surrogatepass")
        for part in (key, tag, data):
            h.update(len(part).to_bytes(8, "little"))
            h.update(part)
    return h.hexdigest()[:32]


def property_datasets(path):
    """The custom per-particle arrays held by checkpoint ``path`` (``elements/property_<name>``)."""
    with h5py.File(path, "r") as f:
        return sorted(n for n in f["elements"] if n.startswith(PROPERTY_PREFIX))


def _spec(gname, name, ndim):
    """(dtype, trailing shape) of ``/gname/name`` in the layout, or None; a custom per-particle
    array (``elements/property_<name>``) is float64 of 1 or 2 dimensions."""
    if gname == "elements" and name.startswith(PROPERTY_PREFIX) and len(name) > len(PROPERTY_PREFIX):
        return _F8, (() if ndim <= 1 else _ANY)
    return SCHEMA.get(gname, {}).get(name)


def _as_schema(gname, name, a):
    """``a`` as the dtype the layout stores for ``/gname/name`` (ValueError for a foreign name)."""
    a = np.asarray(a)
    spec = _spec(gname, name, a.ndim)
    if spec is None:
        if gname in SCHEMA:
            raise ValueError(f"write_checkpoint: /{gname}/{name} is not part of the checkpoint layout")
        return a
    return a if a.dtype == spec[0] else a.astype(spec[0])


def _nonfinite(groups, attrs):
    """``'/group/name'`` (or an attribute name) of the first array holding a NaN (or an infinity
    where none is allowed), or None."""
    items = [(f"/{g}/{n}", a, (g, n) in ALLOW_INF) for g, arrays in groups.items() for n, a in arrays.items()]
    items += [(f"attribute {k}", np.asarray(attrs[k], dtype=np.float64), False)
              for k in FINITE_ATTRS if k in attrs]
    k = first_nonfinite([a for _, a, _ in items], allow_inf={i for i, it in enumerate(items) if it[2]})
    return None if k < 0 else items[k][0]


def _os_reason(exc):
    """One line for an OS error raised by h5py or the os module."""
    m = re.search(r"error message = '([^']*)'", str(exc))
    if m:
        return m.group(1)
    if getattr(exc, "strerror", None):
        return exc.strerror
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _collective(comm, path, tmp, fn):
    """Run ``fn`` (may be None) on this rank; if any rank hit an OS error, remove ``tmp`` (rank 0)
    and raise ``OutputError`` on every rank (the earlier checkpoints stay). One allgather."""
    error = None
    if fn is not None:
        try:
            fn()
        except OSError as exc:
            error = _os_reason(exc)
    errors = comm.allgather(error)
    first = next(((r, e) for r, e in enumerate(errors) if e is not None), None)
    if first is None:
        return
    if comm.is_root:
        try:
            os.remove(tmp)
        except OSError:
            pass
    err = OutputError(f"cannot write checkpoint {path}: {first[1]}" + (f" (rank {first[0]})" if comm.size > 1 else ""))
    err.all_ranks = True       # raised on every rank: no abort needed (pardem.drivers.cli)
    raise err


_NO_FALLOCATE = (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL, errno.ENODEV)


_KEEP_SIZE, _PUNCH_HOLE = 0x01, 0x02     # FALLOC_FL_* of linux/falloc.h


def _fallocate(fd, mode, offset, nbytes):
    """fallocate(2); False where the C library or the file system has none (never emulated by
    writing zeros), OSError for a failure (ENOSPC, EDQUOT, EFBIG)."""
    try:
        fallocate = ctypes.CDLL(None, use_errno=True).fallocate
    except (OSError, AttributeError):
        return False
    fallocate.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    if fallocate(fd, mode, int(offset), int(nbytes)) != 0:
        code = ctypes.get_errno()
        if code in _NO_FALLOCATE:
            return False
        raise OSError(code, os.strerror(code))
    return True


def _reserve(tmp, nbytes):
    """Create ``tmp`` and allocate ``nbytes`` for it on disk, so that a full disk, a quota or a file
    size limit fails here (OSError: ENOSPC, EDQUOT, EFBIG) and not inside HDF5, whose state after
    a failed write cannot be closed cleanly (HDF5 1.10 crashes when the file is released). The
    space is released at once (a probe: HDF5 truncates the file it creates; ``_hold`` then keeps
    the space)."""
    fd = os.open(tmp, os.O_CREAT | os.O_WRONLY | os.O_TRUNC, 0o644)
    try:
        _fallocate(fd, 0, 0, nbytes)
        os.ftruncate(fd, 0)     # back to an empty file: a kill now leaves an empty .tmp
    finally:
        os.close(fd)


def _hold(tmp, nbytes):
    """Allocate the first ``nbytes`` of ``tmp`` on disk, its size unchanged (FALLOC_FL_KEEP_SIZE:
    HDF5 sees the file it wrote), right after HDF5 created it and before it wrote more than its
    superblock (a few hundred bytes in the file's first block). HDF5's writes then land in blocks
    that are already the file's, so a disk filled by another process after ``_reserve``'s probe no
    longer fails them (file systems that write in place: ext4, XFS, tmpfs; not copy-on-write ones
    such as btrfs or ZFS). Raises OSError (ENOSPC, EDQUOT) when the space is not there; the file,
    nearly empty, still closes. ``_release`` gives back what the file did not use."""
    fd = os.open(tmp, os.O_WRONLY)
    try:
        _fallocate(fd, _KEEP_SIZE, 0, nbytes)
    finally:
        os.close(fd)


def _held(comm, tmp, nbytes):
    """Collective, inside the HDF5 file opened with the mpio driver: ``_hold`` on rank 0, and its
    OSError raised on every rank (so that every rank leaves the file, and closes it, together)."""
    error = None
    if comm.is_root:
        try:
            _hold(tmp, nbytes)
        except OSError as exc:
            error = (exc.errno, exc.strerror)
    error = comm.bcast(error)
    if error is not None:
        raise OSError(*error)


def hold_space(path, nbytes):
    """``_hold`` for the other HDF5 writers of ``pardem.io`` (the series file before a flush)."""
    _hold(path, nbytes)


def release_space(path, nbytes):
    """``_release`` of the blocks ``hold_space`` allocated past the end of file ``path``."""
    fd = os.open(path, os.O_WRONLY)
    try:
        _release(fd, nbytes)
    finally:
        os.close(fd)


def _release(fd, nbytes):
    """Free the blocks ``_hold`` allocated past the end of the written file ``fd`` (its size
    unchanged): a hole punched there (tmpfs, XFS) and a truncation to its own size (ext4 frees
    them so). Best effort: a failure only leaves them allocated until the file is removed."""
    size = os.fstat(fd).st_size
    try:
        if nbytes > size:
            _fallocate(fd, _PUNCH_HOLE | _KEEP_SIZE, size, nbytes - size)
        os.ftruncate(fd, size)
    except OSError:
        pass


def _estimated_size(everyone, series, all_attrs):
    """An upper bound of the file's size [bytes]: the data, plus 4 kB of metadata per dataset
    and twice the attributes' text (HDF5 object headers and B-trees are far smaller)."""
    raw = sum(info["nbytes"] for info in everyone) + sum(np.asarray(a).nbytes for a in series.values())
    n_datasets = sum(len(d) for d in everyone[0]["digests"].values()) + len(series)
    text = sum(len(_json(v)) for v in all_attrs.values())
    return int(raw + 4096 * n_datasets + 2 * text + 65536)


def write_checkpoint(path, comm, groups, series, attrs, mode="auto", check_finite=True):
    """Write one checkpoint file collectively (every rank calls it with its own rows).

    groups : {"elements": {name: local rows}, "bonds": {...}}, the rows this rank writes.
    series : {column: array} written as is by rank 0 (other ranks may pass the same or None).
    attrs : root attributes (same on every rank); dicts and lists are stored as JSON text.
    check_finite : refuse (``InstabilityError`` on every rank, nothing written) a NaN in any array
        or an infinity outside ``ALLOW_INF``.
    Raises ``OutputError`` on every rank for an OS error (disk full, permission), after removing
    the ``.tmp``; ``DeckError`` for a malformed ``PARDEM_CHECKPOINT_PAUSE``.
    """
    pause = checkpoint_pause()
    tmp = f"{path}.tmp"
    groups = {g: {n: _as_schema(g, n, a) for n, a in arrays.items()} for g, arrays in groups.items()}
    mine = {"counts": {g: len(next(iter(arrays.values()))) for g, arrays in groups.items()},
            "digests": {g: {n: block_digest(g, n, a) for n, a in arrays.items()} for g, arrays in groups.items()},
            "bad": _nonfinite(groups, attrs) if check_finite else None,
            "nbytes": sum(a.nbytes for arrays in groups.values() for a in arrays.values())}
    everyone = comm.allgather(mine)      # the one exchange of the write's metadata
    for r, info in enumerate(everyone):
        if info["bad"] is not None:
            raise InstabilityError(f"at step {attrs.get('step', '?')}: checkpoint {os.path.basename(path)} "
                                   f"not written: {info['bad']} holds a NaN or infinity on rank {r}")
    if comm.is_root:
        series = {k: np.asarray(a) for k, a in (series or {}).items()}
        series = (series, {k: block_digest("series", k, a) for k, a in series.items()})
    series, series_digests = comm.bcast(series if comm.is_root else None)
    layout = {}
    for gname in groups:
        counts = np.array([info["counts"][gname] for info in everyone], dtype=np.int64)
        layout[gname] = (int(counts[:comm.rank].sum()), int(counts[comm.rank]), int(counts.sum()), counts)
    datasets = sorted(f"{g}/{n}" for g, arrays in groups.items() for n in arrays) + \
        sorted(f"series/{n}" for n in series)
    all_attrs = {**attrs, "layout_version": LAYOUT_VERSION, "pardem_version": pardem.__version__,
                 "n_ranks": comm.size, "owned_counts": layout["elements"][3],
                 "n_elements": layout["elements"][2], "n_bonds": layout["bonds"][2],
                 "datasets": datasets}
    for gname, (_, _, total, counts) in layout.items():   # other groups: rows per writing rank
        if gname not in ("elements", "bonds"):
            all_attrs[f"{gname}_counts"] = counts

    def create(f):
        for k, v in all_attrs.items():
            f.attrs[k] = _json(v) if isinstance(v, (dict, list, tuple)) else v
        f.attrs["attrs_digest"] = attrs_digest({k: f.attrs[k] for k in f.attrs})
        f.attrs["complete"] = 0
        for gname, arrays in groups.items():
            g = f.create_group(gname)
            total, counts = layout[gname][2], layout[gname][3]
            for name, a in arrays.items():
                ds = g.create_dataset(name, shape=(total,) + a.shape[1:], dtype=a.dtype)
                ds.attrs["blocks"] = counts
                ds.attrs["digests"] = np.array([info["digests"][gname][name] for info in everyone], dtype="S32")
        g = f.create_group("series")
        for name, a in series.items():
            ds = g.create_dataset(name, data=a) if not parallel else \
                g.create_dataset(name, shape=a.shape, dtype=a.dtype)
            ds.attrs["blocks"] = np.array([len(a) if a.ndim else 1], dtype=np.int64)
            ds.attrs["digests"] = np.array([series_digests[name]], dtype="S32")

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
    size = _estimated_size(everyone, series, all_attrs)
    _collective(comm, path, tmp, (lambda: _reserve(tmp, size)) if comm.is_root else None)
    if parallel:
        def write_all():
            with h5py.File(tmp, "w", driver="mpio", comm=comm.comm) as f:
                _held(comm, tmp, size)
                create(f)
                fill(f, collective=True)
                if comm.is_root:
                    for name, a in series.items():
                        f["series"][name][...] = a
                f.flush()
                time.sleep(pause)
                f.attrs["complete"] = 1
        _collective(comm, path, tmp, write_all)
    else:
        def create_file():
            with h5py.File(tmp, "w") as f:
                _hold(tmp, size)
                create(f)
        _collective(comm, path, tmp, create_file if comm.is_root else None)

        def fill_file():
            with h5py.File(tmp, "r+") as f:
                fill(f, collective=False)
        for r in range(comm.size):        # ranks take turns with the default (serial) driver
            _collective(comm, path, tmp, fill_file if comm.rank == r else None)
        time.sleep(pause)

        def mark_complete():
            with h5py.File(tmp, "r+") as f:
                f.flush()
                f.attrs["complete"] = 1
        _collective(comm, path, tmp, mark_complete if comm.is_root else None)

    def publish():
        with open(tmp, "rb+") as fh:
            _release(fh.fileno(), size)
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        dfd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    _collective(comm, path, tmp, publish if comm.is_root else None)


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


# ---------------------------------------------------------------------------------------------
# verification

def inspect(path, comm=None, data=True):
    """Verify checkpoint ``path`` and return its root attributes (deck, constants, rng_state
    decoded from JSON; ``series``: {column: array}).

    Raises ``CheckpointError`` (one line) for a missing, unreadable, truncated, incomplete, foreign,
    older-layout, corrupt (a digest differs) or inconsistent file. ``comm``: a
    ``pardem.parallel.communicator.Communicator``; the reading of every dataset for its digests is
    then shared out over the ranks and the verdict is collective (every rank returns the same
    attributes or raises the same error; one allgather, so every rank must call). Without ``comm``
    this process verifies everything. ``data=False`` checks the attributes and the structure only
    (no dataset is read): for a second look at a file already verified with ``data=True``.
    """
    meta, error = None, None
    try:
        _check_path(path)
        refusal = _probe(path)
        if refusal is not None:
            raise CheckpointError(refusal)
        meta, units, gid_bytes = _structure(path)
        if data:
            rank, size = (comm.rank, comm.size) if comm is not None else (0, 1)
            _verify_units(path, units, gid_bytes, rank, size)
    except CheckpointError as err:
        error = str(err)
    except Exception as err:     # noqa: BLE001 -- any failure of a damaged file is one line, and
        # never leaves the other ranks waiting in the verdict's allgather
        text = str(err).splitlines()[0] if str(err) else type(err).__name__
        error = f"--restart {path}: not a readable pardem checkpoint ({type(err).__name__}: {text})"
    if comm is not None and comm.size > 1:
        errors = comm.allgather(error)
        error = next((e for e in errors if e is not None), None)
    if error is not None:
        raise CheckpointError(error)
    return meta


PROBE_SECONDS = 300.0     # a walk of a checkpoint's metadata takes milliseconds; this is a hung reader


def _probe(path, timeout=PROBE_SECONDS):
    """None when a forked child process reads the structure of ``path`` (``_structure``: every
    attribute, group and dataset header, the attributes' digest, the layout; and one row of every
    dataset) and finds it sound; else the one-line reason to refuse the file: the child's own
    ``CheckpointError``, its crash, or its hang (over ``timeout`` [s]).

    A corrupt byte in HDF5's own metadata (object headers, B-trees, heaps) can make the HDF5
    library itself read out of bounds (a segmentation fault in ``H5Aiterate2``), which no check in
    Python can catch. So this process parses only a file whose structure a child has read to the
    end and found consistent with its digests; a file the child refused or crashed on is never
    opened here (whether a damaged file crashes HDF5 depends on the memory around the bad read: the
    same file may crash one process and not another). The child's stderr is closed (no crash
    report) and it leaves no core file. Without ``os.fork`` the file is read in this process."""
    if not hasattr(os, "fork"):
        return None
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:      # the child: no MPI, no Python exit handlers, no output but its verdict
        try:
            import faulthandler
            import resource
            os.close(read_end)
            faulthandler.disable()
            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
            verdict = ""
            try:
                _structure(path)
                _read_first_rows(path)
            except CheckpointError as err:
                verdict = str(err)
            except Exception as err:   # noqa: BLE001 -- any failure of a damaged file is one line
                text = str(err).splitlines()[0] if str(err) else type(err).__name__
                verdict = f"--restart {path}: not a readable pardem checkpoint ({type(err).__name__}: {text})"
            os.write(write_end, ("ok" if not verdict else "no" + verdict).encode("utf-8", "replace")[:4000])
        finally:
            os._exit(0)
    os.close(write_end)
    try:
        return _probe_verdict(path, pid, read_end, timeout)
    finally:
        os.close(read_end)


def _probe_verdict(path, pid, read_end, timeout):
    """Wait for the probe child ``pid`` (killed after ``timeout`` [s]) and read its verdict."""
    deadline = time.monotonic() + timeout
    pause = 0.001
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return (f"--restart {path}: not a readable pardem checkpoint (reading its HDF5 structure did not "
                    f"finish within {timeout:g} s: corrupt metadata, or a file system that does not answer)")
        time.sleep(pause)
        pause = min(2 * pause, 0.05)
    if os.WIFSIGNALED(status):
        try:
            name = signal.Signals(os.WTERMSIG(status)).name
        except ValueError:
            name = f"signal {os.WTERMSIG(status)}"
        return (f"--restart {path}: the file is corrupt: its HDF5 metadata (object headers, B-trees) crashes "
                f"the HDF5 library ({name} in a test reading); restart from another checkpoint")
    chunks = []
    while True:
        chunk = os.read(read_end, 4096)
        if not chunk:
            break
        chunks.append(chunk)
    verdict = b"".join(chunks).decode("utf-8", "replace")
    if verdict == "ok":
        return None
    if verdict.startswith("no") and len(verdict) > 2:
        return " ".join(verdict[2:].split())
    return f"--restart {path}: not a readable pardem checkpoint (its test reading ended without a verdict)"


def _read_first_rows(path):
    """The first and last row of every dataset (the layout HDF5 parsed points into the file)."""
    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.shape and obj.shape[0] > 0:
            obj[:1], obj[-1:]
    with h5py.File(path, "r") as f:
        f.visititems(visit)


def _check_path(path):
    if str(path).endswith(".tmp"):
        raise CheckpointError(f"--restart {path}: a .tmp file is an incomplete checkpoint (its write did not "
                              f"finish); restart from a complete checkpoint-*.h5")
    if not os.path.exists(path):
        raise CheckpointError(f"--restart {path}: no such file")
    if not os.path.isfile(path):
        raise CheckpointError(f"--restart {path}: not a regular file (a checkpoint is a checkpoint-*.h5 file)")


def _int_attr(path, attrs, name, lo=0):
    v = attrs.get(name)
    a = np.asarray(v) if v is not None else None
    if a is None or a.shape != () or a.dtype.kind not in "iu" or int(a) < lo:
        raise CheckpointError(f"--restart {path}: attribute {name} = {v!r} is not an integer >= {lo}")
    return int(a)


def _count_attr(path, attrs, name, n):
    v = attrs.get(name)
    a = np.asarray(v) if v is not None else None
    if a is None or a.shape != (n,) or a.dtype.kind not in "iu" or np.any(a < 0):
        raise CheckpointError(f"--restart {path}: attribute {name} is not {n} counts >= 0")
    return a.astype(np.int64)


def _json_attr(path, attrs, name, required=True):
    if name not in attrs:
        if required:
            raise CheckpointError(f"--restart {path}: attribute {name} is missing")
        return None
    try:
        return json.loads(attrs[name])
    except (TypeError, ValueError) as err:
        raise CheckpointError(f"--restart {path}: attribute {name} is not valid JSON ({err})") from None


def _structure(path):
    """Root attributes and the file's structure against them (every rank; reads no data)."""
    try:
        with h5py.File(path, "r") as f:
            attrs = {k: f.attrs[k] for k in f.attrs}
            version = attrs.get("layout_version")
            if version is None:
                raise CheckpointError(f"--restart {path}: not a pardem checkpoint (no layout_version attribute)")
            if np.asarray(version).shape != () or np.asarray(version).dtype.kind not in "iu":
                raise CheckpointError(f"--restart {path}: layout_version = {version!r} is not an integer")
            if int(version) != LAYOUT_VERSION:
                older = (" (written by an older pardem, without checksums: continue that run with the "
                         "pardem that wrote it, or start it again)") if int(version) < LAYOUT_VERSION else ""
                raise CheckpointError(f"--restart {path}: checkpoint layout version {int(version)}, this pardem "
                                      f"({pardem.__version__}) reads version {LAYOUT_VERSION}{older}")
            complete = np.asarray(attrs.get("complete", 0))
            if complete.shape != () or complete.dtype.kind not in "iu" or int(complete) != 1:
                raise CheckpointError(f"--restart {path}: the checkpoint is incomplete (its write was interrupted)")
            if attrs.get("attrs_digest") != attrs_digest(attrs):
                raise CheckpointError(f"--restart {path}: the root attributes (deck, constants, step, time, "
                                      f"counts, ...) do not match their digest: the file was modified or is corrupt")
            units, gid_check = _check_layout(path, f, attrs)
            series = {}
            for k in f["series"]:
                series[k] = f["series"][k][...]
    except CheckpointError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as err:
        text = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise CheckpointError(f"--restart {path}: not a readable pardem checkpoint ({text})") from None
    meta = dict(attrs)
    for k in ("deck", "constants", "rng_state"):
        meta[k] = _json_attr(path, attrs, k)
    for k in ("deck", "constants"):
        if not isinstance(meta[k], dict):
            raise CheckpointError(f"--restart {path}: attribute {k} is not a JSON object")
    _check_clock(path, attrs, meta["constants"])
    for k in ("attrs_digest", "datasets"):
        meta.pop(k, None)
    meta["series"] = series
    return meta, units, gid_check


def _check_layout(path, f, attrs):
    """Counts, dataset list, dtypes, shapes and block tables; returns the data units to verify."""
    n_ranks = _int_attr(path, attrs, "n_ranks", lo=1)
    n_el = _int_attr(path, attrs, "n_elements")
    n_bonds = _int_attr(path, attrs, "n_bonds")
    owned = _count_attr(path, attrs, "owned_counts", n_ranks)
    if int(owned.sum()) != n_el:
        raise CheckpointError(f"--restart {path}: owned_counts sum to {int(owned.sum())}, n_elements is {n_el}")
    listed = _json_attr(path, attrs, "datasets")
    present = []
    f.visititems(lambda name, obj: present.append(name) if isinstance(obj, h5py.Dataset) else None)
    if not isinstance(listed, list) or sorted(present) != sorted(listed):
        extra = sorted(set(present) - set(listed or [])) if isinstance(listed, list) else present
        missing = sorted(set(listed) - set(present)) if isinstance(listed, list) else []
        what = f"dataset /{missing[0]} is missing" if missing else f"unexpected dataset /{extra[0]}"
        raise CheckpointError(f"--restart {path}: {what}")
    rows = {"elements": n_el, "bonds": n_bonds}
    for gname in f:
        if gname in ("elements", "bonds", "series"):
            continue
        if gname not in SCHEMA:
            raise CheckpointError(f"--restart {path}: unexpected group /{gname}")
        counts = _count_attr(path, attrs, f"{gname}_counts", n_ranks)
        rows[gname] = int(counts.sum())
    for gname in ("elements", "bonds"):
        if gname not in f:
            raise CheckpointError(f"--restart {path}: group /{gname} is missing")
    units = []
    for gname in sorted(f):
        group = f[gname]
        if gname != "series":
            for name in REQUIRED[gname]:
                if name not in group:
                    raise CheckpointError(f"--restart {path}: dataset /{gname}/{name} is missing")
        for name in sorted(group):
            ds = group[name]
            where = f"/{gname}/{name}"
            if gname != "series":
                if _spec(gname, name, ds.ndim) is None:
                    raise CheckpointError(f"--restart {path}: unexpected dataset {where}")
                dtype, tail = _spec(gname, name, ds.ndim)
                if ds.dtype != dtype:
                    raise CheckpointError(f"--restart {path}: {where} has dtype {ds.dtype}, expected {dtype}")
                if len(ds.shape) != 1 + len(tail) or any(t is not None and t != s for t, s in zip(tail, ds.shape[1:])):
                    raise CheckpointError(f"--restart {path}: {where} has shape {ds.shape}, expected "
                                          f"(rows,{','.join('*' if t is None else str(t) for t in tail)})")
                if ds.shape[0] != rows[gname]:
                    raise CheckpointError(f"--restart {path}: {where} has {ds.shape[0]} rows, expected {rows[gname]}")
            blocks = ds.attrs.get("blocks")
            digests = ds.attrs.get("digests")
            b = np.asarray(blocks) if blocks is not None else None
            d = np.asarray(digests) if digests is not None else None
            n_rows = ds.shape[0] if ds.shape else 1
            if (b is None or d is None or b.ndim != 1 or b.dtype.kind not in "iu" or np.any(b < 0)
                    or int(b.sum()) != n_rows or d.shape != b.shape or d.dtype.kind != "S"):
                raise CheckpointError(f"--restart {path}: {where} has no valid checksum table (blocks, digests)")
            if gname in ("elements", "contacts") and not np.array_equal(
                    b, owned if gname == "elements" else np.asarray(attrs[f"{gname}_counts"])):
                raise CheckpointError(f"--restart {path}: {where} blocks differ from the rank counts")
            row_bytes = ds.dtype.itemsize * int(np.prod(ds.shape[1:], dtype=np.int64))
            off = 0
            for k, n in enumerate(b.tolist()):
                units.append((gname, name, k, off, n, n * row_bytes, d[k].decode("ascii", "replace")))
                off += n
    gid_bytes = 8 * (n_el + 3 * n_bonds + 2 * rows.get("contacts", 0))
    return units, gid_bytes


def _check_clock(path, attrs, constants):
    """step >= 0 and time consistent with the step and the time step of the run."""
    step = _int_attr(path, attrs, "step")
    t = np.asarray(attrs.get("time", np.nan))
    if t.shape != () or t.dtype.kind != "f" or not np.isfinite(t) or t < 0:
        raise CheckpointError(f"--restart {path}: attribute time = {attrs.get('time')!r} is not a finite time >= 0")
    t = float(t)
    rs = _json_attr(path, attrs, "run_state", required=False)
    expected = None
    try:
        if isinstance(rs, dict) and "clock" in rs and "dt" in rs:
            s0, t0 = int(rs["clock"][0]), float(rs["clock"][1])
            if s0 > step:
                raise CheckpointError(f"--restart {path}: run_state clock step {s0} is after the step {step}")
            expected = t0 + (step - s0) * float(rs["dt"])
        elif "dt" in constants:
            expected = step * float(constants["dt"])
    except (TypeError, ValueError, IndexError) as err:
        raise CheckpointError(f"--restart {path}: run_state or constants.dt is malformed ({err})") from None
    # the run computes time with this very formula: only the last bits of a product may differ
    if expected is not None and not abs(t - expected) <= 1e-12 * max(abs(t), abs(expected)) + 1e-300:
        raise CheckpointError(f"--restart {path}: time = {t!r} s does not match step {step} and the run's "
                              f"time step ({expected!r} s)")
    for name in ("plate_positions", "plate_velocities"):
        if name in attrs:
            a = np.asarray(attrs[name])
            if a.dtype.kind != "f" or not np.all(np.isfinite(a)):
                raise CheckpointError(f"--restart {path}: attribute {name} is not finite numbers")


def _share(units, gid_bytes, size):
    """Owner rank of each unit and of the gid check: largest first to the least loaded rank
    (deterministic, so every rank computes the same sharing)."""
    load = [0] * size
    owner = [0] * (len(units) + 1)      # the last task is the gid check
    costs = [u[5] for u in units] + [gid_bytes]
    for k in sorted(range(len(costs)), key=lambda k: (-costs[k], k)):
        r = min(range(size), key=lambda q: (load[q], q))
        owner[k] = r
        load[r] += costs[k]
    return owner[:-1], owner[-1]


def _verify_units(path, units, gid_bytes, rank, size):
    """Digests, finiteness and gid consistency of this rank's share of the data units."""
    owner, gid_owner = _share(units, gid_bytes, size)
    with h5py.File(path, "r") as f:
        for k, (gname, name, block, off, n, _, digest) in enumerate(units):
            if owner[k] != rank:
                continue
            ds = f[gname][name]
            a = ds[off:off + n] if ds.shape else ds[()]
            where = f"/{gname}/{name}" + (f" (block {block}, rows {off}..{off + n - 1})" if n else "")
            if block_digest(gname, name, a) != digest:
                raise CheckpointError(f"--restart {path}: {where} does not match its checksum: the file is corrupt")
            if gname != "series" and a.dtype.kind == "f" and a.size:
                if first_nonfinite([a], allow_inf={0} if (gname, name) in ALLOW_INF else ()) >= 0:
                    raise CheckpointError(f"--restart {path}: {where} holds a NaN or infinity")
                if (gname, name) in POSITIVE and not np.all(a > 0.0):
                    raise CheckpointError(f"--restart {path}: {where} holds a value <= 0")
        if gid_owner == rank:
            _verify_gids(path, f)


def _verify_gids(path, f):
    """Element gids unique and >= 0; bond gids unique, ends ordered and existing; contact ends existing."""
    eg = np.sort(f["elements"]["gid"][...])
    if len(eg) and (eg[0] < 0 or np.any(eg[1:] == eg[:-1])):
        raise CheckpointError(f"--restart {path}: /elements/gid holds a negative or repeated gid")

    def missing(ends):
        if len(eg) == 0:
            return len(ends) > 0
        pos = np.minimum(np.searchsorted(eg, ends), len(eg) - 1)
        return bool(np.any(eg[pos] != ends))

    for gname in ("bonds", "contacts"):
        if gname not in f:
            continue
        g = f[gname]
        total = g["gid_i"].shape[0]
        for start in range(0, total, _CHUNK):
            gi, gj = g["gid_i"][start:start + _CHUNK], g["gid_j"][start:start + _CHUNK]
            if missing(gi) or missing(gj):
                raise CheckpointError(f"--restart {path}: /{gname}/gid_i or gid_j names an element not in the file")
            if gname == "bonds" and np.any(gi >= gj):
                raise CheckpointError(f"--restart {path}: /bonds/gid_i is not below gid_j for every bond")
    bg = np.sort(f["bonds"]["gid"][...])
    if len(bg) and (bg[0] < 0 or np.any(bg[1:] == bg[:-1])):
        raise CheckpointError(f"--restart {path}: /bonds/gid holds a negative or repeated gid")


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
