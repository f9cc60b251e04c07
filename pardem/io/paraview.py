"""ParaView output: one time series of VTK XML unstructured grids, one piece per rank.

File layout in ``directory``::

    pardem.pvd                        the collection to open: one DataSet per snapshot, with
                                      timestep = simulation time [s] (rank 0 rewrites it atomically)
    snapshot-SSSSSSSS.pvtu            one parallel grid per snapshot (rank 0): array declarations
                                      and the list of pieces
    snapshot-SSSSSSSS-rRRRR.vtu       the piece of rank RRRR at step SSSSSSSS (that rank writes it,
                                      with meshio, base64 binary zlib-compressed)

``SSSSSSSS`` is the step count (8 digits) and ``RRRR`` the rank (4 digits). A rank that holds no
point at a snapshot writes no piece, and the .pvtu leaves it out: the .pvtu lists exactly the
pieces that exist. The .pvd lists the snapshots written by this writer object and, for a restarted
run (``resume_step``), those already in the directory up to that step.

Contents of a piece (SI units):

* points: the rank's owned elements (rows ``[0, n_owned)``, in row order), then the ghost elements
  that its counted bonds reach, at their current centres ``x`` [m];
* point data: ``radius`` [m]; ``velocity`` [m/s] (3 components); ``displacement`` = ``x - x0`` [m]
  (3 components, ``x0`` the reference position); ``rank`` (int32, the writing rank); ``gid``
  (int64, element global id); ``vtkGhostType`` (uint8: 0 owned, 1 = DUPLICATEPOINT for a ghost
  copy of an element another rank owns; ParaView's Glyph filter skips duplicate points, so every
  element is drawn once). A ghost's velocity is the one the rank last received, i.e. the owner's
  half-step value: the owner's piece holds the end-of-step one;
* cells: one ``line`` per bond counted once on this rank (those whose first end, the lower gid,
  it owns: ``bonds.i < n_owned``), from the lower-gid end to the higher;
* cell data: ``axial_force`` = ``ka (L - L0 (1 - p))`` [N], positive in tension, ``L`` the current
  distance between the ends [m], ``p`` the plastic strain (elastic axial force, without damping;
  0 for a broken bond); ``state`` (int32: 0 intact, 1 broken in tension, 2 broken in shear: a
  broken bond stays drawn, filter it with Threshold on ``state``); ``plastic`` (the densification
  strain p); ``young`` [Pa].

Every bond appears in exactly one piece and every element is owned in exactly one piece, so the
union of the pieces of a snapshot is the whole system, whatever the number of ranks.

Opening in ParaView:

1. File > Open > ``pardem.pvd``, Apply: one dataset with a time series (the time slider steps
   through the snapshots, labelled in seconds). The lines are the bonds: colour by
   ``axial_force`` (cell data) to see tension (> 0) and compression (< 0).
2. Elements as spheres: select the dataset, Filters > Glyph; Glyph Type = Sphere;
   Scale Array = ``radius``, Scale Factor = 1 (the Sphere source has radius 0.5, so set its Radius
   to 1 in the glyph-type properties, or use Scale Factor = 2, for true-size spheres);
   Glyph Mode = All Points; Apply. Colour by ``displacement`` or ``velocity``.
   Ghost duplicates (``vtkGhostType`` = 1) are not glyphed.

2D runs (``pardem.engine.plane``) need nothing else: the points lie at z = 0 and the velocities have
no z component; view along z (-Z button) and glyph spheres, or Glyph Type = 2D Glyph, Circle, filled.
"""
import os
import re
import sys

import meshio
import numpy as np

from pardem.errors import OutputError
from pardem.physics.bond_state import BOND_INTACT
from pardem.triggers import as_trigger
from pardem.physics.beam_axial import elastic_axial_force

PVD_NAME = "pardem.pvd"

# (name, dtype, components) of the point and cell arrays; the .pvtu declares exactly these
POINT_ARRAYS = (("radius", np.float64, 1), ("velocity", np.float64, 3),
                ("displacement", np.float64, 3), ("rank", np.int32, 1), ("gid", np.int64, 1),
                ("vtkGhostType", np.uint8, 1))
CELL_ARRAYS = (("axial_force", np.float64, 1), ("state", np.int32, 1), ("plastic", np.float64, 1),
               ("young", np.float64, 1))
POINTS_DTYPE = np.float64

GHOST_OWNED = np.uint8(0)
GHOST_DUPLICATE = np.uint8(1)   # vtkDataSetAttributes::DUPLICATEPOINT

_VTK_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.float32): "Float32",
              np.dtype(np.int64): "Int64", np.dtype(np.int32): "Int32", np.dtype(np.uint8): "UInt8"}
_BYTE_ORDER = "LittleEndian" if sys.byteorder == "little" else "BigEndian"


def snapshot_name(step):
    return f"snapshot-{int(step):08d}.pvtu"


def piece_name(step, rank):
    return f"snapshot-{int(step):08d}-r{int(rank):04d}.vtu"


def piece_mesh(elements, bonds, rank):
    """The meshio Mesh of one rank's piece (see the module docstring for its content)."""
    e, b = elements, bonds
    n_owned = e.n_owned
    once = b.counted_once(n_owned)
    bi, bj = b.i[once].astype(np.int64), b.j[once].astype(np.int64)
    ghosts = np.unique(bj[bj >= n_owned])          # the first end is owned by construction
    rows = np.concatenate([np.arange(n_owned, dtype=np.int64), ghosts])
    local = np.full(e.n_total, -1, dtype=np.int64)
    local[rows] = np.arange(len(rows))
    lines = np.stack([local[bi], local[bj]], axis=1).reshape(-1, 2)

    ghost_type = np.full(len(rows), GHOST_DUPLICATE, dtype=np.uint8)
    ghost_type[:n_owned] = GHOST_OWNED
    point_data = {
        "radius": e.radius[rows],
        "velocity": e.v[rows],
        "displacement": e.x[rows] - e.x0[rows],
        "rank": np.full(len(rows), rank),
        "gid": e.gid[rows],
        "vtkGhostType": ghost_type,
    }
    state = b.state[once]
    axial = elastic_axial_force(bi, bj, e.x, b.L0[once], b.ka[once], b.plastic[once])
    cell_data = {
        "axial_force": np.where(state == BOND_INTACT, axial, 0.0),
        "state": state,
        "plastic": b.plastic[once],
        "young": b.young[once],
    }
    point_data = {k: np.ascontiguousarray(point_data[k], dtype=t).reshape(-1, c) if c > 1
                  else np.ascontiguousarray(point_data[k], dtype=t) for k, t, c in POINT_ARRAYS}
    cell_data = {k: [np.ascontiguousarray(cell_data[k], dtype=t)] for k, t, _ in CELL_ARRAYS}
    points = np.ascontiguousarray(e.x[rows], dtype=POINTS_DTYPE).reshape(-1, 3)
    return meshio.Mesh(points, [("line", lines)], point_data=point_data, cell_data=cell_data)


def _declarations(tag, arrays):
    out = []
    for name, dtype, comps in arrays:
        nc = f' NumberOfComponents="{comps}"' if comps > 1 else ""
        out.append(f'      <PDataArray type="{_VTK_TYPES[np.dtype(dtype)]}" Name="{name}"{nc}/>')
    return [f"    <{tag}>", *out, f"    </{tag}>"]


def pvtu_text(pieces):
    """The XML of a PUnstructuredGrid listing the piece file names ``pieces`` (relative paths)."""
    lines = ['<?xml version="1.0"?>',
             f'<VTKFile type="PUnstructuredGrid" version="0.1" byte_order="{_BYTE_ORDER}">',
             '  <PUnstructuredGrid GhostLevel="0">',
             *_declarations("PPointData", POINT_ARRAYS),
             *_declarations("PCellData", CELL_ARRAYS),
             "    <PPoints>",
             f'      <PDataArray type="{_VTK_TYPES[np.dtype(POINTS_DTYPE)]}" NumberOfComponents="3"/>',
             "    </PPoints>",
             *(f'    <Piece Source="{p}"/>' for p in pieces),
             "  </PUnstructuredGrid>",
             "</VTKFile>", ""]
    return "\n".join(lines)


def pvd_text(entries):
    """The XML of a ParaView collection from ``(time [s], file name)`` pairs, in that order."""
    lines = ['<?xml version="1.0"?>',
             f'<VTKFile type="Collection" version="0.1" byte_order="{_BYTE_ORDER}">',
             "  <Collection>",
             *(f'    <DataSet timestep="{float(t)!r}" group="" part="0" file="{f}"/>' for t, f in entries),
             "  </Collection>",
             "</VTKFile>", ""]
    return "\n".join(lines)


def _write_atomic(path, text):
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)


class ParaViewWriter:
    """Operation writing a ParaView snapshot of the simulation on the steps of ``trigger`` (an int
    period [steps] or a ``pardem.triggers.Trigger``), and after the last step of every run
    with ``at_end``.

    Collective: every rank of ``comm`` (a ``Communicator``) must call it at the same steps, as
    ``Simulation.run`` does. Each rank writes its piece; then, once all pieces exist, rank 0 writes
    the snapshot's .pvtu and rewrites ``pardem.pvd``. A failure on any rank raises
    ``RuntimeError`` on every rank (``OutputError``, one, when the file system refused). Units and file layout: see the module docstring.
    """

    def __init__(self, directory, comm, trigger, resume_step=None, dt=None, at_end=False):
        self.trigger, self.at_end = as_trigger(trigger), bool(at_end)
        self.directory = os.fspath(directory)
        self.comm = comm
        self.snapshots = {}   # step -> (time [s], .pvtu name), on rank 0
        if comm.is_root:
            os.makedirs(self.directory, exist_ok=True)
            if resume_step is not None:    # a restart continues the series written before it
                for name in os.listdir(self.directory):
                    if name.startswith("snapshot-") and name.endswith(".pvtu"):
                        step = int(name[len("snapshot-"):-len(".pvtu")])
                        if step <= resume_step:
                            self.snapshots[step] = (step * dt, name)
        comm.barrier()

    def __call__(self, sim):
        comm, step = self.comm, int(sim.step_count)
        name = piece_name(step, comm.rank)
        n_points, error = 0, None
        try:
            mesh = piece_mesh(sim.elements, sim.bonds, comm.rank)
            n_points = len(mesh.points)
            if n_points:
                path = os.path.join(self.directory, name)
                tmp = f"{path}.tmp{os.getpid()}"
                mesh.write(tmp, file_format="vtu")
                os.replace(tmp, path)
        except Exception as err:   # reported on every rank below, so no rank waits forever
            error = f"{type(err).__name__}: {err}"
        # this allgather is the barrier: it completes on rank 0 only once every rank has finished
        # (or failed) its piece, so the .pvtu below never lists a piece still being written
        info = self.comm.allgather((n_points, error))
        failed = [f"rank {r}: {e}" for r, (_, e) in enumerate(info) if e is not None]
        if failed:
            raise _failure(f"ParaView snapshot at step {step} not written: " + "; ".join(failed))

        error = None
        if comm.is_root:
            try:
                pieces = [piece_name(step, r) for r, (n, _) in enumerate(info) if n > 0]
                pvtu = snapshot_name(step)
                _write_atomic(os.path.join(self.directory, pvtu), pvtu_text(pieces))
                self.snapshots[step] = (float(sim.time), pvtu)
                entries = [self.snapshots[s] for s in sorted(self.snapshots)]
                _write_atomic(os.path.join(self.directory, PVD_NAME), pvd_text(entries))
            except Exception as err:
                error = f"{type(err).__name__}: {err}"
        if comm.size > 1:
            error = comm.bcast(error)   # every rank waits for rank 0's files, and shares its fate
        if error is not None:
            raise _failure(f"ParaView snapshot at step {step}: rank 0 failed to write the "
                           f".pvtu/.pvd: {error}")


def _failure(message):
    """The error every rank raises for a failed snapshot: ``OutputError`` (a ``RuntimeError``;
    ``all_ranks``: the drivers end in one line, exit 4) when a rank's file system refused
    (``OSError`` and its kinds), else ``RuntimeError``."""
    if re.search(r"\b\w*(OSError|PermissionError|FileNotFoundError|IsADirectoryError|NotADirectoryError):", message):
        err = OutputError(message)
        err.all_ranks = True
        return err
    return RuntimeError(message)
