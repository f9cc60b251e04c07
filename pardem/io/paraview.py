"""ParaView output: one time series of VTK XML unstructured grids, one piece per rank.

File layout in ``directory``::

    pardem.pvd                        the collection to open: one DataSet per snapshot, with
                                      timestep = simulation time [s] (rank 0 rewrites it atomically)
    snapshot-SSSSSSSS.pvtu            one parallel grid per snapshot (rank 0): array declarations
                                      and the list of pieces
    snapshot-SSSSSSSS-rRRRR.vtu       the piece of rank RRRR at step SSSSSSSS (that rank writes it,
                                      with meshio, base64 binary zlib-compressed)

    contacts.pvd, contacts-SSSSSSSS.vtu   the contact network (rank 0; with ``contacts`` and a
                                      simulation that has contacts): one line per touching pair
    cell.pvd, cell-SSSSSSSS.vtu       the periodic cell as one hexahedron (rank 0; with a cell)

``SSSSSSSS`` is the step count (8 digits) and ``RRRR`` the rank (4 digits). A rank that holds no
point at a snapshot writes no piece, and the .pvtu leaves it out: the .pvtu lists exactly the
pieces that exist. The .pvd lists the snapshots written by this writer object and, for a restarted
run (``resume_step``), the earlier ones up to that step: those the collection ``previous`` lists
(the .pvd of the run the checkpoint came from, in another folder: entries read from it with their
paths made relative to this directory, so a chain of restarts stays one collection) or, without
``previous``, the snapshots already in this directory. The rule: every earlier snapshot at a step
<= ``resume_step`` is kept; those after it (written by the earlier run after its checkpoint, before
it stopped) are dropped, since the restarted run writes those steps again. So the last run's
``pardem.pvd`` lists every step of the whole run once, in order.

Contents of a piece (SI units):

* points: the rank's owned elements (rows ``[0, n_owned)``, in row order), then the ghost elements
  that its counted bonds reach, at their current centres ``x`` [m];
* point data: ``radius`` [m]; ``velocity`` [m/s] (3 components); ``displacement`` = ``x - x0`` [m]
  (3 components, ``x0`` the reference position); ``spin`` (angular velocity, world frame [rad/s],
  3); ``orientation`` (quaternion ``(w, x, y, z)``, body to world, 4; constant when the run does not
  integrate orientations, ``Integration.orientation``); ``force`` [N] and ``torque`` [N m] (3 each:
  the loads of the last force evaluation, every contribution included); ``coordination`` (int32:
  touching contacts of the element, -1 for a ghost copy, whose count its owner writes);
  ``rank`` (int32, the writing rank); ``gid``
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

The contact network (``contacts-SSSSSSSS.vtu``): per touching pair (``contact_writer.gather_contacts``,
each pair once, sorted by gids) one ``line`` between its own two points, the centre of grain i
and ``x_i + branch`` (the centre of j's image across a periodic boundary, so no line crosses the
box); point data ``gid``; cell data ``gid_i``, ``gid_j`` (int64), ``normal_force``,
``tangential_force``, ``normal_damping``, ``tangential_damping`` (on i [N], 3 each, as
``contact_writer`` writes them), ``force_magnitude`` (``|sum of the four|`` [N]), ``overlap``
[m], ``sliding`` (uint8). Colour the lines by ``force_magnitude`` (Tube filter, radius by it) for
the force chains.

The cell (``cell-SSSSSSSS.vtu``): one ``hexahedron`` from ``cell.lo`` to ``cell.hi`` [m]; cell
data ``length`` [m] (3), ``strain`` (the accumulated log strain of the edges, 3), ``rate`` [1/s]
(3). View it as Wireframe or Outline.

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
import xml.etree.ElementTree as ET

import meshio
import numpy as np

from pardem.errors import OutputError
from pardem.io.contact_writer import coordination as contact_coordination, gather_contacts
from pardem.physics.bond_state import BOND_INTACT
from pardem.triggers import as_trigger
from pardem.physics.beam_axial import elastic_axial_force

PVD_NAME = "pardem.pvd"
CONTACTS_PVD, CELL_PVD = "contacts.pvd", "cell.pvd"
COLLECTIONS = (PVD_NAME, CONTACTS_PVD, CELL_PVD)

# (name, dtype, components) of the point and cell arrays; the .pvtu declares exactly these
POINT_ARRAYS = (("radius", np.float64, 1), ("velocity", np.float64, 3),
                ("displacement", np.float64, 3), ("spin", np.float64, 3),
                ("orientation", np.float64, 4), ("force", np.float64, 3), ("torque", np.float64, 3),
                ("coordination", np.int32, 1), ("rank", np.int32, 1), ("gid", np.int64, 1),
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


def contacts_name(step):
    return f"contacts-{int(step):08d}.vtu"


def cell_name(step):
    return f"cell-{int(step):08d}.vtu"


_STEP_OF = re.compile(r"-(\d{8})(?:-r\d{4})?\.(?:pvtu|vtu)$")


def step_of(file_name):
    """The step count in a snapshot file name (``...-SSSSSSSS.pvtu``/``.vtu``), or None."""
    m = _STEP_OF.search(os.path.basename(file_name))
    return None if m is None else int(m.group(1))


def piece_name(step, rank):
    return f"snapshot-{int(step):08d}-r{int(rank):04d}.vtu"


def piece_mesh(elements, bonds, rank, coordination=None):
    """The meshio Mesh of one rank's piece (see the module docstring for its content).
    ``coordination``: contacts per row [n_total] (``contact_writer.coordination``; None: zeros)."""
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
    z = np.zeros(len(rows), dtype=np.int32) if coordination is None else coordination[rows]
    z[n_owned:] = -1
    point_data = {
        "radius": e.radius[rows],
        "velocity": e.v[rows],
        "displacement": e.x[rows] - e.x0[rows],
        "spin": e.w[rows],
        "orientation": e.q[rows],
        "force": e.f[rows],
        "torque": e.t[rows],
        "coordination": z,
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


def contacts_mesh(gid, values):
    """The meshio Mesh of the contact network ``(gid [m, 2], values [m, 20])`` of
    ``contact_writer.gather_contacts`` (module docstring)."""
    m = len(gid)
    xi = values[:, 17:20]
    points = np.empty((2 * m, 3))
    points[0::2], points[1::2] = xi, xi + values[:, 0:3]
    total = values[:, 3:6] + values[:, 6:9] + values[:, 11:14] + values[:, 14:17]
    cell_data = {"gid_i": gid[:, 0], "gid_j": gid[:, 1],
                 "normal_force": values[:, 3:6], "tangential_force": values[:, 6:9],
                 "normal_damping": values[:, 11:14], "tangential_damping": values[:, 14:17],
                 "force_magnitude": np.linalg.norm(total, axis=1), "overlap": values[:, 9],
                 "sliding": values[:, 10].astype(np.uint8)}
    return meshio.Mesh(points, [("line", np.arange(2 * m, dtype=np.int64).reshape(m, 2))],
                       point_data={"gid": np.ascontiguousarray(gid.reshape(-1), dtype=np.int64)},
                       cell_data={k: [np.ascontiguousarray(v)] for k, v in cell_data.items()})


# VTK_HEXAHEDRON's corner order: the lower face counter-clockwise, then the upper one
_HEX_CORNERS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0),
                         (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], dtype=np.float64)


def cell_mesh(cell):
    """The meshio Mesh of a ``PeriodicCell``: one hexahedron with corners ``lo + H c`` [m], ``H``
    the edge vectors (``cell.edges``: a box, or a parallelepiped when simple shear tilts it), ``c``
    the unit cube's corners."""
    lo, length = np.asarray(cell.lo, float), np.asarray(cell.length, float)
    edges = np.asarray(getattr(cell, "edges", np.diag(length)), float)
    points = lo + _HEX_CORNERS @ edges.T
    data = {"length": length, "strain": np.asarray(cell.strain, float), "rate": np.asarray(cell.rate, float)}
    return meshio.Mesh(points, [("hexahedron", np.arange(8, dtype=np.int64).reshape(1, 8))],
                       cell_data={k: [v.reshape(1, 3)] for k, v in data.items()})


def read_pvd(path):
    """The ``(time [s], file)`` entries of a ParaView collection, in its order (files as written:
    relative to the collection's folder)."""
    root = ET.parse(path).getroot()
    return [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]


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
    the snapshot's .pvtu, the contact network (``contacts``, when the simulation has contacts) and
    the cell (when it has a periodic cell), and rewrites the collections. A failure on any rank
    raises ``RuntimeError`` on every rank (``OutputError``, one, when the file system refused). Units and file layout: see the module docstring.
    ``resume_step`` [steps], ``dt`` [s], ``previous`` (the earlier run's ParaView folder): a
    restarted run's collections continue the earlier ones (module docstring).
    """

    def __init__(self, directory, comm, trigger, resume_step=None, dt=None, at_end=False,
                 contacts=True, previous=None):
        self.trigger, self.at_end = as_trigger(trigger), bool(at_end)
        self.directory = os.fspath(directory)
        self.comm = comm
        self.contacts = bool(contacts)
        self.collections = {name: {} for name in COLLECTIONS}   # step -> (time [s], file), rank 0
        error = None
        if comm.is_root:
            try:
                os.makedirs(self.directory, exist_ok=True)
                if resume_step is not None:    # a restart continues the series written before it
                    self._resume(int(resume_step), dt, previous)
            except (OSError, ET.ParseError) as err:
                error = f"{type(err).__name__}: {err}"
        if comm.size > 1:
            error = comm.bcast(error)
        else:
            comm.barrier()
        if error is not None:
            raise RuntimeError(f"ParaView output in {self.directory}: cannot continue the earlier "
                               f"collections: {error}")

    @property
    def snapshots(self):
        """step -> (time [s], .pvtu name) of the points' collection (rank 0)."""
        return self.collections[PVD_NAME]

    def _resume(self, resume_step, dt, previous):
        if previous is not None and os.path.abspath(previous) != os.path.abspath(self.directory):
            for name, entries in self.collections.items():
                path = os.path.join(previous, name)
                if not os.path.isfile(path):
                    continue
                for t, f in read_pvd(path):
                    step = step_of(f)
                    if step is not None and step <= resume_step:
                        entries[step] = (t, os.path.relpath(os.path.join(previous, f), self.directory))
            return
        prefixes = {"snapshot-": PVD_NAME, "contacts-": CONTACTS_PVD, "cell-": CELL_PVD}
        for name in os.listdir(self.directory):
            step = step_of(name)
            kind = next((c for p, c in prefixes.items() if name.startswith(p)), None)
            if step is None or kind is None or step > resume_step or "-r" in name[-10:]:
                continue
            if kind == PVD_NAME and not name.endswith(".pvtu"):
                continue
            self.collections[kind][step] = (step * dt, name)

    def __call__(self, sim):
        comm, step = self.comm, int(sim.step_count)
        name = piece_name(step, comm.rank)
        n_points, error = 0, None
        try:
            coord = contact_coordination(sim) if getattr(sim, "contacts", None) is not None else None
            mesh = piece_mesh(sim.elements, sim.bonds, comm.rank, coord)
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
        network = None
        if self.contacts and getattr(sim, "contacts", None) is not None:
            network = gather_contacts(sim)     # collective

        error = None
        if comm.is_root:
            try:
                pieces = [piece_name(step, r) for r, (n, _) in enumerate(info) if n > 0]
                pvtu = snapshot_name(step)
                _write_atomic(os.path.join(self.directory, pvtu), pvtu_text(pieces))
                t = float(sim.time)
                self.collections[PVD_NAME][step] = (t, pvtu)
                if network is not None:
                    self._write_mesh(contacts_mesh(*network), contacts_name(step))
                    self.collections[CONTACTS_PVD][step] = (t, contacts_name(step))
                if getattr(sim, "cell", None) is not None:
                    self._write_mesh(cell_mesh(sim.cell), cell_name(step))
                    self.collections[CELL_PVD][step] = (t, cell_name(step))
                for pvd, entries in self.collections.items():
                    if entries:
                        _write_atomic(os.path.join(self.directory, pvd),
                                      pvd_text([entries[s] for s in sorted(entries)]))
            except Exception as err:
                error = f"{type(err).__name__}: {err}"
        if comm.size > 1:
            error = comm.bcast(error)   # every rank waits for rank 0's files, and shares its fate
        if error is not None:
            raise _failure(f"ParaView snapshot at step {step}: rank 0 failed to write the "
                           f".pvtu/.pvd: {error}")

    def _write_mesh(self, mesh, name):
        path = os.path.join(self.directory, name)
        tmp = f"{path}.tmp{os.getpid()}"
        mesh.write(tmp, file_format="vtu")
        os.replace(tmp, path)


def _failure(message):
    """The error every rank raises for a failed snapshot: ``OutputError`` (a ``RuntimeError``;
    ``all_ranks``: the drivers end in one line, exit 4) when a rank's file system refused
    (``OSError`` and its kinds), else ``RuntimeError``."""
    if re.search(r"\b\w*(OSError|PermissionError|FileNotFoundError|IsADirectoryError|NotADirectoryError):", message):
        err = OutputError(message)
        err.all_ranks = True
        return err
    return RuntimeError(message)
