"""Checkpoint integrity (issue 16, items 2 and 6): no corrupt or edited checkpoint loads silently,
and a failed write keeps the earlier checkpoints.

Two small checkpoints written by pardem itself: a bonded compression with frictional walls (1 rank,
through the driver: elements with wall history, bonds, series) and a granular packing with loaded
contacts (elements, contacts). Every dataset gets bytes flipped at several offsets inside its data
region (its file offset from h5py's ``get_offset``), every root attribute is edited, and each
result must be refused by ``inspect`` with a one-line ``CheckpointError``; the untouched files load.
"""
import ast
import errno
import json
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np

from pardem import restart
import pytest

from pardem.config import DeckError
from pardem.errors import InstabilityError, OutputError
from pardem.io import checkpoint
from pardem.io.checkpoint import CheckpointError, inspect, write_checkpoint
from pardem.parallel.communicator import Communicator
from _util import granular_case

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
HERE = os.path.dirname(os.path.abspath(__file__))
SMALL = ["--set", "domain.box=[0.004,0.004,0.004]", "--set", "plates.friction=0.3", "--quiet"]


def compress(n, args, env=None, timeout=600):
    cmd = ([MPIEXEC, "-n", str(n)] if n > 1 else []) + [sys.executable, "-m", "pardem.drivers.compress", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env={**os.environ, **(env or {})})


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("integrity")
    p = compress(1, [*SMALL, "--steps", "20", "--set", "checkpoint.every_steps=20", "--set", "checkpoint.at_end=false",
                     "--out", str(tmp / "bonded")])
    bonded = tmp / "bonded" / "checkpoints" / "checkpoint-0000000020.h5"
    assert bonded.exists(), p.stderr
    # a granular packing: 4^3 spheres 1.95 R apart in a periodic cell, shaken so that springs load
    R = 0.5e-3
    g = (np.arange(4) + 0.5) * 1.95 * R
    pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    case = granular_case(Communicator(), pos, np.full(len(pos), R), 2500.0, "hertz_mindlin",
                          {"young": 72e9, "poisson": 0.2, "friction": 0.5}, np.zeros(3), np.full(3, 4 * 1.95 * R),
                          1e-9, 0.05 * R)
    case.sim.elements.v[:] = np.random.default_rng(3).normal(size=(len(pos), 3)) * 1e-2
    case.sim.run(5)
    gran = tmp / "granular.h5"
    restart.save(case.sim, extras=case.extras, path=str(gran))
    return {"bonded": bonded, "granular": gran}


def refused(path, *words):
    with pytest.raises(CheckpointError) as err:
        inspect(str(path))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("--restart"), msg
    for w in words:
        assert w in msg, msg
    return msg


def datasets(path):
    out = []
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.append((n, o.id.get_offset(), o.id.get_storage_size(), o.dtype.itemsize))
                     if isinstance(o, h5py.Dataset) else None)
    return out


def test_the_untouched_files_load(files):
    meta = inspect(str(files["bonded"]))
    assert int(meta["step"]) == 20 and meta["deck"]["plates"]["friction"] == 0.3
    assert int(meta["n_elements"]) > 0 and int(meta["n_bonds"]) > 0 and "step" in meta["series"]
    with h5py.File(files["bonded"], "r") as f:
        assert f["elements"]["wall_h"].shape[1] == 2          # frictional walls: their history is in
    meta = inspect(str(files["granular"]))
    with h5py.File(files["granular"], "r") as f:
        h = f["contacts"]["history"][...]
    assert len(h) and np.any(h != 0), "the granular file holds loaded contact springs"
    assert int(np.sum(meta["contacts_counts"])) == len(h)


@pytest.mark.parametrize("which", ["bonded", "granular"])
def test_every_byte_flip_in_a_data_region_is_refused(files, tmp_path, which):
    src = files[which]
    rng = np.random.default_rng(11)
    tried = 0
    for name, offset, size, item in datasets(src):
        if offset is None or size == 0:    # an empty dataset has no data region
            continue
        spots = sorted({0, size - 1, size // 2, *rng.integers(0, size, 3).tolist()})
        edits = [(s, None) for s in spots]
        # 0.0 overwritten by an all-ones NaN, the word pattern Fletcher32 cannot see
        if item == 8:
            edits.append((item * int(rng.integers(0, size // item)), b"\xff" * 8))
        for spot, data in edits:
            bad = tmp_path / "bad.h5"
            shutil.copyfile(src, bad)
            with open(bad, "r+b") as fh:
                fh.seek(offset + spot)
                old = fh.read(len(data) if data else 1)
                new = data if data else bytes([old[0] ^ 0xFF])
                if new == old:
                    continue
                fh.seek(offset + spot)
                fh.write(new)
            refused(bad, f"/{name}", "checksum")
            tried += 1
    assert tried >= 100 if which == "bonded" else tried >= 20


def _edit_json(key_path, value):
    def edit(f):
        attr = key_path[0]
        d = json.loads(f.attrs[attr])
        node = d
        for k in key_path[1:-1]:
            node = node[k]
        node[key_path[-1]] = value
        f.attrs[attr] = json.dumps(d, sort_keys=True)
    return edit


def _set(name, value):
    def edit(f):
        f.attrs[name] = value
    return edit


def _delete(name):
    def edit(f):
        del f.attrs[name]
    return edit


def _perturb(name):
    """Some other value of the same kind for root attribute ``name``."""
    def edit(f):
        v = f.attrs[name]
        if isinstance(v, str):
            f.attrs[name] = v + " " if not v.startswith("{") else v[:-1] + ', "x": 1}' if v != "{}" else '{"x": 1}'
        else:
            a = np.asarray(v)
            if a.size == 0:
                f.attrs[name] = np.zeros(1, dtype=a.dtype)
            elif a.dtype.kind == "f":
                f.attrs[name] = a * (1 + 1e-12) + 1e-300
            else:
                f.attrs[name] = a + 1
    return edit


SEMANTIC = {
    "deck young = 2e8": _edit_json(("deck", "bonds", "young"), 2e8),
    "deck plate_speed": _edit_json(("deck", "loading", "plate_speed"), 0.123),
    "deck not JSON": _set("deck", "{bonds"),
    "deck missing": _delete("deck"),
    "constants not JSON": _set("constants", "[1,"),
    "constants dt": _edit_json(("constants", "dt"), 1e-8),
    "step = -100": _set("step", -100),
    "step = 21": _set("step", 21),
    "step as a float": _set("step", 20.0),
    "time doubled": lambda f: f.attrs.__setitem__("time", 2 * f.attrs["time"]),
    "plate moved": lambda f: f.attrs.__setitem__("plate_positions", f.attrs["plate_positions"] + [0.0, 1e-6]),
    "owned_counts": lambda f: f.attrs.__setitem__("owned_counts", f.attrs["owned_counts"] - 1),
    "n_elements": lambda f: f.attrs.__setitem__("n_elements", f.attrs["n_elements"] + 1),
    "layout_version 1": _set("layout_version", 1),
    "layout_version 99": _set("layout_version", 99),
    "complete = 0": _set("complete", 0),
    "complete = 2": _set("complete", 2),
    "complete as a string": _set("complete", "1"),
    "digest edited": _set("attrs_digest", "0" * 32),
    "digest deleted": _delete("attrs_digest"),
    "new attribute": _set("injected", 1),
    "/series/step deleted": lambda f: f.__delitem__("series/step"),
    "/elements/mass deleted": lambda f: f.__delitem__("elements/mass"),
    "dataset added": lambda f: f["elements"].create_dataset("extra", data=np.zeros(3)),
    "string-typed mass": lambda f: _replace(f, "elements/mass", lambda a: a.astype("S24")),
    "int32 gid": lambda f: _replace(f, "elements/gid", lambda a: a.astype(np.int32)),
    "repeated gid": lambda f: _replace(f, "elements/gid", lambda a: np.r_[a[:1], a[:-1]]),
    "bond end gid out of range": lambda f: _replace(f, "bonds/gid_j", lambda a: a - 60596),
    "x with a NaN": lambda f: _replace(f, "elements/x", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 4,
                                                                           np.nan, a)),
    "bond digests edited": lambda f: f["bonds"]["ka"].attrs.__setitem__("digests", np.array([b"0" * 32])),
    "bond blocks edited": lambda f: f["bonds"]["ka"].attrs.__setitem__("blocks", np.array([1, 1343])),
    "checksum table deleted": lambda f: f["elements"]["x"].attrs.__delitem__("digests"),
}


def _replace(f, name, fn):
    """Dataset ``name`` rewritten as ``fn(data)``, its checksum table copied over."""
    ds = f[name]
    data, attrs = fn(ds[...]), dict(ds.attrs)
    del f[name]
    new = f.create_dataset(name, data=data)
    for k, v in attrs.items():
        new.attrs[k] = v


@pytest.mark.parametrize("edit", sorted(SEMANTIC))
def test_every_edited_attribute_or_dataset_is_refused(files, tmp_path, edit):
    bad = tmp_path / "bad.h5"
    shutil.copyfile(files["bonded"], bad)
    with h5py.File(bad, "r+") as f:
        SEMANTIC[edit](f)
    msg = refused(bad)
    if edit == "layout_version 1":
        assert "older pardem" in msg
    if edit.startswith("complete"):
        assert "incomplete" in msg


@pytest.mark.parametrize("which", ["bonded", "granular"])
def test_any_root_attribute_changed_or_deleted_is_refused(files, tmp_path, which):
    with h5py.File(files[which], "r") as f:
        names = sorted(f.attrs)
    assert {"deck", "constants", "step", "time", "plate_positions", "owned_counts", "run_state"} <= set(names)
    for name in names:
        for make in (_perturb, _delete):
            bad = tmp_path / "bad.h5"
            shutil.copyfile(files[which], bad)
            with h5py.File(bad, "r+") as f:
                make(name)(f)
            refused(bad)


def test_paths_that_are_not_complete_checkpoints_are_refused(files, tmp_path):
    tmp = tmp_path / "checkpoint-0000000020.h5.tmp"
    shutil.copyfile(files["bonded"], tmp)
    refused(tmp, ".tmp")
    refused(tmp_path, "not a regular file")
    refused(tmp_path / "none.h5", "no such file")
    (tmp_path / "text.h5").write_text("not hdf5\n")
    refused(tmp_path / "text.h5", "not a readable")
    half = tmp_path / "half.h5"
    data = open(files["bonded"], "rb").read()
    half.write_bytes(data[:len(data) // 2])
    refused(half)


def test_verification_is_shared_over_ranks_deterministically():
    units = [("elements", f"d{k}", 0, 0, 10, 100 * (k + 1), "") for k in range(7)]
    a = checkpoint._share(units, 350, 3)
    assert a == checkpoint._share(units, 350, 3)
    owner, gid_owner = a
    load = [0, 0, 0]
    for u, r in zip(units, owner):
        load[r] += u[5]
    load[gid_owner] += 350
    # greedy largest-first: no rank carries more than the mean plus the largest task
    assert max(load) <= sum(load) / 3 + 700 and set(owner) == {0, 1, 2}


def test_pause_environment_is_validated(monkeypatch, tmp_path):
    monkeypatch.setenv("PARDEM_CHECKPOINT_PAUSE", "0.25")
    assert checkpoint.checkpoint_pause() == 0.25
    for bad in ("abc", "-1", "nan", "1e9", "inf", "1,5"):
        monkeypatch.setenv("PARDEM_CHECKPOINT_PAUSE", bad)
        with pytest.raises(DeckError, match="PARDEM_CHECKPOINT_PAUSE") as err:
            write_checkpoint(str(tmp_path / "c.h5"), Communicator(), *_payload(4))
        assert "\n" not in str(err.value) and "seconds" in str(err.value)
        assert os.listdir(tmp_path) == []          # refused before any file exists


def _payload(n, step=1, first_gid=0):
    """A small valid payload: n elements (gids from ``first_gid``), no bonds."""
    rng = np.random.default_rng(n)
    el = {k: rng.random((n, 3)) for k in ("x", "v", "w", "f", "t", "x0", "x_build")}
    el.update(q=np.tile([1.0, 0, 0, 0], (n, 1)), radius=np.full(n, 1e-3), mass=np.full(n, 1e-6),
              inertia=np.full(n, 1e-13), gid=np.arange(first_gid, first_gid + n, dtype=np.int64), flags=np.zeros(n, np.uint8))
    bonds = {k: np.zeros((0, 3) if k in ("u1", "p1", "u2", "p2") else 0,
                         dtype=np.int64 if k.startswith("gid") else np.uint8 if k == "state" else np.float64)
             for k in checkpoint.BOND_DATASETS}
    attrs = {"step": step, "time": step * 1e-7, "deck": {"kind": "test"}, "constants": {"dt": 1e-7},
             "rng_state": {"generator": None}, "slab_axis": 0, "plate_positions": np.zeros(2),
             "plate_velocities": np.zeros(2)}
    return {"elements": el, "bonds": bonds}, {"step": np.arange(3)}, attrs


def test_a_nonfinite_state_is_never_written(tmp_path):
    groups, series, attrs = _payload(5)
    groups["elements"]["w"][2, 1] = np.nan
    with pytest.raises(InstabilityError, match="/elements/w"):
        write_checkpoint(str(tmp_path / "c.h5"), Communicator(), groups, series, attrs)
    groups, series, attrs = _payload(5)
    groups["bonds"]["f_tensile"] = np.array([np.inf])     # inf strength: an unbreakable bond, allowed
    for k, v in groups["bonds"].items():
        if k != "f_tensile":
            groups["bonds"][k] = np.zeros((1,) + v.shape[1:], v.dtype)
    groups["bonds"]["gid_j"] = np.array([1])
    write_checkpoint(str(tmp_path / "ok.h5"), Communicator(), groups, series, attrs)
    inspect(str(tmp_path / "ok.h5"))
    attrs["time"] = float("inf")
    with pytest.raises(InstabilityError, match="time"):
        write_checkpoint(str(tmp_path / "c.h5"), Communicator(), groups, series, attrs)
    assert sorted(os.listdir(tmp_path)) == ["ok.h5"]


def test_disk_full_during_a_write_keeps_the_earlier_checkpoint(tmp_path, monkeypatch):
    """h5py's dataset write monkeypatched to fail as a full disk does (ENOSPC)."""
    comm = Communicator()
    first = tmp_path / checkpoint.checkpoint_name(1)
    write_checkpoint(str(first), comm, *_payload(50, step=1))
    real = h5py.Dataset.__setitem__

    def full(self, key, value):
        if self.name == "/elements/q":
            raise OSError(errno.ENOSPC, "Can't write data (file write failed: time = x, filename = 'f', "
                          "file descriptor = 5, errno = 28, error message = 'No space left on device', buf = 0)")
        return real(self, key, value)
    monkeypatch.setattr(h5py.Dataset, "__setitem__", full)
    second = tmp_path / checkpoint.checkpoint_name(2)
    with pytest.raises(OutputError) as err:
        write_checkpoint(str(second), comm, *_payload(50, step=2))
    msg = str(err.value)
    assert "\n" not in msg and str(second) in msg and "No space left on device" in msg
    assert sorted(os.listdir(tmp_path)) == [first.name]          # no .tmp left, the first one kept
    assert int(inspect(str(first))["step"]) == 1


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
@pytest.mark.parametrize("mode", ["mpio", "serial"])
def test_a_real_os_error_on_two_ranks_removes_the_tmp(tmp_path, mode):
    """The file size limit (RLIMIT_FSIZE, EFBIG from write(2)) stands in for a full disk: both ranks
    raise the same OutputError, the .tmp is gone and the smaller earlier checkpoint verifies."""
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.join(HERE, "mpi", "integrity_fsize.py"),
                        str(tmp_path), mode], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    lines = sorted(line for line in p.stdout.splitlines() if "OutputError" in line)
    assert len(lines) == 2, p.stdout + p.stderr
    assert lines[0].split(":", 1)[1] == lines[1].split(":", 1)[1]     # the same message on both ranks
    assert "File too large" in lines[0] and "big.h5" in lines[0]
    assert sorted(os.listdir(tmp_path)) == ["small.h5"]
    inspect(str(tmp_path / "small.h5"))


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_two_rank_verdict_is_collective(files, tmp_path):
    """inspect(path, comm): both ranks raise the same error, whichever rank read the bad block."""
    bad = tmp_path / "bad.h5"
    for name in ("elements/x", "bonds/p2", "series/time"):
        shutil.copyfile(files["bonded"], bad)
        offset = next(o for n, o, _, _ in datasets(bad) if n == name)
        with open(bad, "r+b") as fh:
            fh.seek(offset + 3)
            b = fh.read(1)
            fh.seek(offset + 3)
            fh.write(bytes([b[0] ^ 0x10]))
        p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.join(HERE, "mpi", "integrity_inspect.py"),
                            str(bad)], capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stdout + p.stderr
        lines = sorted(p.stdout.splitlines())
        assert len(lines) == 2 and lines[0][1:] == lines[1][1:] and f"/{name}" in lines[0], p.stdout
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.join(HERE, "mpi", "integrity_inspect.py"),
                        str(files["bonded"])], capture_output=True, text=True, timeout=300)
    assert sorted(p.stdout.splitlines()) == ["0 ok 20", "1 ok 20"], p.stdout + p.stderr


@pytest.mark.skipif(MPIEXEC is None, reason="needs mpiexec")
def test_two_rank_restart_from_a_corrupt_checkpoint_exits_2_in_one_line(tmp_path):
    p = compress(2, [*SMALL, "--steps", "20", "--set", "checkpoint.every_steps=20", "--set", "checkpoint.at_end=false",
                     "--out", str(tmp_path / "run")])
    ck = tmp_path / "run" / "checkpoints" / "checkpoint-0000000020.h5"
    assert ck.exists(), p.stderr
    offset, size = next((o, s) for n, o, s, _ in datasets(ck) if n == "bonds/ka")
    with open(ck, "r+b") as fh:
        fh.seek(offset + size // 3)
        b = fh.read(1)
        fh.seek(offset + size // 3)
        fh.write(bytes([b[0] ^ 0x01]))
    p = compress(2, ["--quiet", "--restart", str(ck), "--steps", "40", "--out", str(tmp_path / "restart")])
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "/bonds/ka" in lines[0] and "checksum" in lines[0], p.stderr


def _with_bond(groups, gid_i, gid_j):
    for k, v in groups["bonds"].items():
        groups["bonds"][k] = np.zeros((1,) + v.shape[1:], v.dtype)
    groups["bonds"]["gid_i"], groups["bonds"]["gid_j"] = np.array([gid_i]), np.array([gid_j])
    return groups


@pytest.mark.parametrize("case", ["repeated element gid", "negative gid", "bond end missing", "bond ends unordered",
                                  "time off the clock", "negative mass"])
def test_consistency_is_checked_beyond_the_checksums(tmp_path, case):
    """A file whose digests are right but whose content is inconsistent (a writer's bug) is refused."""
    groups, series, attrs = _payload(6)
    el = groups["elements"]
    words = {"repeated element gid": "repeated gid", "negative gid": "negative", "bond end missing": "not in the file",
             "bond ends unordered": "below gid_j", "time off the clock": "does not match step",
             "negative mass": "<= 0"}[case]
    if case == "repeated element gid":
        el["gid"][3] = el["gid"][2]
    elif case == "negative gid":
        el["gid"][0] = -7
    elif case == "bond end missing":
        _with_bond(groups, 1, 60596)
    elif case == "bond ends unordered":
        _with_bond(groups, 4, 2)
    elif case == "time off the clock":
        attrs["time"] = 1.5 * attrs["time"]
    elif case == "negative mass":
        el["mass"][1] = -1e-6
    path = tmp_path / "c.h5"
    write_checkpoint(str(path), Communicator(), groups, series, attrs)
    refused(path, words)


# -- corrupt HDF5 metadata: no crash of the reader ---------------------------------------------------

SWEEP = r"""
import random, sys
import numpy as np
from pardem.io.checkpoint import CheckpointError, inspect


def same(a, b):
    return a.keys() == b.keys() and all(same(a[k], b[k]) if isinstance(a[k], dict) else
                                        np.array_equal(np.asarray(a[k]), np.asarray(b[k])) for k in a)

src, bad, lo, hi, extra = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
data = open(src, "rb").read()
good = inspect(src)
spots = list(range(lo, min(hi, len(data))))
spots += random.Random(5).sample(range(0, min(len(data), 4096)), extra)
for off in spots:
    with open(bad, "wb") as fh:
        fh.write(data[:off] + bytes([data[off] ^ 0xFF]) + data[off + 1:])
    try:
        meta = inspect(bad)
        print(off, "accepted" if same(meta, good) else "ACCEPTED CHANGED")
    except CheckpointError as err:
        print(off, "refused", repr(str(err)))
    sys.stdout.flush()
"""


def test_byte_flips_in_the_hdf5_metadata_never_crash(files, tmp_path):
    """Every byte of 1700..1799 of a checkpoint (the root attributes' metadata, where a flip made
    HDF5 itself crash with SIGSEGV in ``H5Aiterate2``: the old verification died at 1709, 1710,
    1711, 1720, 1722-1725, 1737, ... of this file, signal 11) and 100 random bytes of its first
    4 KB (superblock, root group, object headers), flipped one at a time and the file verified in
    one process: it never crashes, and every flip is refused in one line or leaves a file equal in
    content (a flip in bytes HDF5 does not read). (A sample: each verification forks a reader, and
    a sweep of every byte of the first 4 KB takes about half an hour on a loaded 2-core machine.)"""
    p = subprocess.run([sys.executable, "-c", SWEEP, str(files["granular"]), str(tmp_path / "bad.h5"), "1700", "1800",
                        "100"], capture_output=True, text=True, timeout=1800)
    lines = p.stdout.splitlines()
    assert p.returncode == 0, f"the verification crashed (exit {p.returncode}) after {lines[-1:]}: {p.stderr[-2000:]}"
    assert len(lines) == 100 + 100
    refused = [ln for ln in lines if " refused " in ln]
    for ln in refused:
        msg = ast.literal_eval(ln.split(" refused ", 1)[1])
        assert msg.startswith("--restart") and "\n" not in msg, ln
    crashes = [ln for ln in refused if "crashes the HDF5 library" in ln]
    # the refusals by the child's crash: the flips that crashed the old verification in this process
    assert crashes, "no flip of this range crashes HDF5 any more: pick the range again (superblock, root attributes)"
    # an accepted flip leaves every attribute and the series as written (the datasets' digests
    # matched too, or it would have been refused)
    assert not [ln for ln in lines if "CHANGED" in ln]
    assert len(refused) >= len(lines) // 2
    first = int(crashes[0].split()[0])
    bad = tmp_path / "crash.h5"
    data = bytearray(files["granular"].read_bytes())
    data[first] ^= 0xFF
    bad.write_bytes(bytes(data))
    p = compress(1, ["--quiet", "--restart", str(bad), "--out", str(tmp_path / "restart")])
    assert p.returncode == 2, p.stderr[-2000:]
    lines = p.stderr.strip().splitlines()
    # one line: the crash again, or, in this other process, another refusal of the same bytes
    # (whether HDF5 crashes depends on the memory around its bad read)
    assert len(lines) == 1 and lines[0].startswith(f"pardem: error: --restart {bad}"), p.stderr[-2000:]
    assert not (tmp_path / "restart").exists()
