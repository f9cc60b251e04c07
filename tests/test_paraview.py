"""ParaView output (pardem.io.paraview): pieces read back with meshio and compared with the state.

Expected values are computed here independently: bond lengths and forces in NumPy from the element
positions, the bonded pairs and the ghosts a rank needs from the lattice's own pair list.
"""
import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from _util import ran_to_end

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.domains.ordered import ordered_lattice
from pardem.io.paraview import ParaViewWriter
from pardem.engine.simulation import Simulation
from pardem.engine.state import Elements, Plates
from pardem.triggers import Periodic

from _util import FakeComm

HERE = os.path.dirname(__file__)
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
R = 0.5e-3
YOUNG, RATIO = 2e8, 0.6
POINT_NAMES = {"radius", "velocity", "displacement", "spin", "orientation", "force", "torque",
               "coordination", "rank", "gid", "vtkGhostType"}
CELL_NAMES = {"axial_force", "state", "plastic", "young"}


# ---------------------------------------------------------------------------- helpers

def lattice_sim(dims=(4, 3, 2), seed=1):
    """A bonded lattice of dims elements, displaced and moving; its pairs (gids) from the lattice."""
    pos, pairs, frame = ordered_lattice(2 * R * np.array(dims, float), R)
    e = Elements.from_spheres(pos, R, 1000.0)
    b = make_bonds(e, pairs, BeamMaterial(YOUNG, RATIO, 0.3, 0.1), frame)
    rng = np.random.default_rng(seed)
    e.x += rng.normal(scale=0.02 * R, size=e.x.shape)
    e.v[:] = rng.normal(scale=0.1, size=e.v.shape)
    sim = Simulation(FakeComm(), e, b, Plates.pair(0, -1.0, 1.0, 0.0, 1e6), 1e-7)
    return sim, np.sort(pairs, axis=1)


def at_step(sim, step):
    sim.step_count = step
    sim.time = step * sim.dt


def expected_force(x, gid_pairs):
    """ka (L - L0) of the bonds joining element rows ``gid_pairs`` (gid == row here), textbook ka."""
    r = RATIO * R
    L0 = 2.0 * R                      # lattice spacing: the bonds are made between touching spheres
    L = np.linalg.norm(x[gid_pairs[:, 1]] - x[gid_pairs[:, 0]], axis=1)
    return YOUNG * np.pi * r * r / L0 * (L - L0)


def line_gids(mesh):
    """Lines of a piece as (lower gid, higher gid) pairs, and their order kept."""
    lines = mesh.cells_dict.get("line", np.zeros((0, 2), int))
    g = mesh.point_data["gid"][lines]
    return g


def by_pair(gid_pairs, values):
    return {(int(a), int(b)): v for (a, b), v in zip(gid_pairs, values)}


def data_arrays(node):
    """{name: (type, components)} of the DataArray / PDataArray children of an XML node."""
    return {a.get("Name"): (a.get("type"), int(a.get("NumberOfComponents", "1"))) for a in node}


def check_pvtu(path):
    """Parse a .pvtu; check each piece exists and declares exactly the pvtu's arrays and types.

    Returns the piece paths."""
    root = ET.parse(path).getroot()
    assert root.get("type") == "PUnstructuredGrid"
    grid = root.find("PUnstructuredGrid")
    p_point = data_arrays(grid.find("PPointData"))
    p_cell = data_arrays(grid.find("PCellData"))
    assert set(p_point) == POINT_NAMES and set(p_cell) == CELL_NAMES
    assert p_point["vtkGhostType"] == ("UInt8", 1) and p_point["gid"] == ("Int64", 1)
    assert p_point["velocity"] == ("Float64", 3) and p_point["displacement"] == ("Float64", 3)
    pieces = [os.path.join(os.path.dirname(path), p.get("Source")) for p in grid.findall("Piece")]
    for piece in pieces:
        assert os.path.isfile(piece), piece
        vtu = ET.parse(piece).getroot().find("UnstructuredGrid/Piece")
        assert data_arrays(vtu.find("PointData")) == p_point
        assert data_arrays(vtu.find("CellData")) == p_cell
        assert data_arrays(vtu.find("Points")) == {"Points": data_arrays(grid.find("PPoints"))[None]}
    return pieces


_VTK_DTYPES = {"Float64": np.float64, "Float32": np.float32, "Int64": np.int64, "Int32": np.int32,
               "UInt8": np.uint8}


def read_point_data(path):
    """``(points, {name: array})`` of a VTU piece written by meshio (binary, zlib, UInt32 header),
    decoded here from the XML: meshio's reader fails on a piece with an empty cell block (a
    granular piece has no bond lines)."""
    import base64
    import zlib
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")

    def decode(da):
        text = da.text.strip()
        n_blocks = int(np.frombuffer(base64.b64decode(text[:8])[:4], np.uint32)[0])
        n_header = 4 * (3 + n_blocks)
        chars = 4 * -(-n_header // 3)
        sizes = np.frombuffer(base64.b64decode(text[:chars])[:n_header], np.uint32)[3:]
        raw, data, at = b"", base64.b64decode(text[chars:]), 0
        for size in sizes:
            raw += zlib.decompress(data[at:at + int(size)])
            at += int(size)
        a = np.frombuffer(raw, _VTK_DTYPES[da.get("type")])
        comps = int(da.get("NumberOfComponents", "1"))
        return a.reshape(-1, comps) if comps > 1 else a

    points = decode(piece.find("Points/DataArray"))
    return points, {da.get("Name"): decode(da) for da in piece.find("PointData")}


def read_pvd(path):
    root = ET.parse(path).getroot()
    assert root.get("type") == "Collection"
    return [(float(d.get("timestep")), d.get("file")) for d in root.find("Collection")]


# ---------------------------------------------------------------------------- serial

def test_serial_snapshots_match_the_state(tmp_path):
    sim, pairs = lattice_sim()
    e = sim.elements
    n = e.n_total
    out = tmp_path / "vtk"
    writer = ParaViewWriter(out, sim.comm, trigger=5)
    assert writer.trigger == Periodic(5) and not writer.at_end

    snaps = {}
    for step in (5, 10):
        at_step(sim, step)
        writer(sim)
        snaps[step] = dict(x=e.x.copy(), v=e.v.copy())
        e.x += 1e-3 * R                      # the next snapshot must see a different state
        e.v *= -2.0

    assert read_pvd(out / "pardem.pvd") == [(5 * sim.dt, "snapshot-00000005.pvtu"),
                                            (10 * sim.dt, "snapshot-00000010.pvtu")]
    for step, ref in snaps.items():
        pieces = check_pvtu(out / f"snapshot-{step:08d}.pvtu")
        assert [os.path.basename(p) for p in pieces] == [f"snapshot-{step:08d}-r0000.vtu"]
        m = meshio.read(pieces[0])
        pd = m.point_data
        assert len(m.points) == n
        order = np.argsort(pd["gid"])
        assert np.array_equal(pd["gid"][order], np.arange(n))       # every element once
        np.testing.assert_array_equal(m.points[order], ref["x"])
        np.testing.assert_array_equal(pd["radius"][order], np.full(n, R))
        np.testing.assert_array_equal(pd["velocity"][order], ref["v"])
        np.testing.assert_allclose(pd["displacement"][order], ref["x"] - e.x0, rtol=0, atol=1e-18)
        assert np.all(pd["vtkGhostType"] == 0) and np.all(pd["rank"] == 0)

        g = line_gids(m)
        assert len(g) == len(pairs) == sim.bonds.n == 3 * 4 * 3 * 2 - 4 * 3 - 3 * 2 - 4 * 2
        assert np.all(g[:, 0] < g[:, 1])                           # from the lower gid end
        assert set(map(tuple, g.tolist())) == set(map(tuple, pairs.tolist()))
        cd = m.cell_data_dict
        got = by_pair(g, cd["axial_force"]["line"])
        want = by_pair(pairs, expected_force(ref["x"], pairs))
        assert max(abs(got[k] - want[k]) for k in want) <= 1e-9 * max(abs(v) for v in want.values())
        assert np.any(np.array(list(want.values())) > 0) and np.any(np.array(list(want.values())) < 0)
        np.testing.assert_array_equal(cd["state"]["line"], 0)
        np.testing.assert_allclose(cd["young"]["line"], YOUNG, rtol=1e-12)

    # a second call at the same step (10) replaces its entry instead of listing it twice
    writer(sim)
    assert [f for _, f in read_pvd(out / "pardem.pvd")] == ["snapshot-00000005.pvtu",
                                                            "snapshot-00000010.pvtu"]


def test_piece_with_ghosts_holds_owned_plus_reached_ghosts(tmp_path):
    """Rows past n_owned act as ghosts: only those a counted bond reaches are written, flagged 1."""
    sim, pairs = lattice_sim(dims=(5, 3, 3), seed=2)
    e = sim.elements
    m_owned = 20                                 # gids follow x: rows [0, 20) are a slab
    e.n_owned = m_owned
    at_step(sim, 3)
    ParaViewWriter(tmp_path, sim.comm, 1)(sim)
    m = meshio.read(tmp_path / "snapshot-00000003-r0000.vtu")
    pd = m.point_data

    counted = pairs[pairs[:, 0] < m_owned]        # lower-gid end owned
    reached = np.unique(counted[counted[:, 1] >= m_owned, 1])
    assert 0 < len(reached) < e.n_total - m_owned
    owned = pd["vtkGhostType"] == 0
    assert np.array_equal(pd["gid"][owned], np.arange(m_owned))
    assert np.array_equal(np.sort(pd["gid"][~owned]), reached)
    assert np.all(pd["vtkGhostType"][~owned] == 1)
    np.testing.assert_array_equal(m.points, e.x[pd["gid"]])
    g = line_gids(m)
    assert set(map(tuple, g.tolist())) == set(map(tuple, counted.tolist())) and len(g) == len(counted)
    got = by_pair(g, m.cell_data_dict["axial_force"]["line"])
    want = by_pair(counted, expected_force(e.x, counted))
    assert max(abs(got[k] - want[k]) for k in want) <= 1e-9 * max(abs(v) for v in want.values())


class _TwoRankView(FakeComm):
    """Rank 0 of two, whose partner reports an empty piece (checks the .pvtu skips it)."""
    size = 2

    class _Raw:
        def allgather(self, obj):
            return [obj, (0, None)]

    comm = _Raw()

    def bcast(self, obj, root=0):
        return obj

    def barrier(self):
        pass


def test_empty_pieces_are_left_out_consistently(tmp_path):
    sim, _ = lattice_sim(dims=(2, 2, 2))
    at_step(sim, 4)
    ParaViewWriter(tmp_path, _TwoRankView(), 2)(sim)
    pieces = check_pvtu(tmp_path / "snapshot-00000004.pvtu")
    assert [os.path.basename(p) for p in pieces] == ["snapshot-00000004-r0000.vtu"]

    # a rank with no element at all writes no piece and no error
    e = sim.elements
    sim.elements = Elements.unpack([e.pack(np.zeros(0, dtype=np.int64))], 0)
    sim.bonds = type(sim.bonds).unpack([sim.bonds.pack(np.zeros(0, dtype=np.int64))], True)
    at_step(sim, 6)
    ParaViewWriter(tmp_path / "empty", sim.comm, 2)(sim)
    assert not (tmp_path / "empty" / "snapshot-00000006-r0000.vtu").exists()
    assert check_pvtu(tmp_path / "empty" / "snapshot-00000006.pvtu") == []
    assert read_pvd(tmp_path / "empty" / "pardem.pvd") == [(6 * sim.dt, "snapshot-00000006.pvtu")]


def test_trigger_must_be_positive(tmp_path):
    with pytest.raises(ValueError, match="trigger = 0: expected a period"):
        ParaViewWriter(tmp_path, FakeComm(), 0)


# ---------------------------------------------------------------------------- parallel

@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_two_ranks_make_one_consistent_series(tmp_path):
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.join(HERE, "mpi", "paraview_run.py"),
                        str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert ran_to_end(p), p.stderr
    run = json.loads((tmp_path / "run.json").read_text())
    k = run["k"]
    assert run["ranks"] == 2 and run["n_elements"] == k**3
    assert run["n_bonds"] == 3 * k * k * (k - 1)
    vtk = tmp_path / "vtk"

    pvd = read_pvd(vtk / "pardem.pvd")
    assert [f for _, f in pvd] == [f"snapshot-{s:08d}.pvtu" for s in run["steps"]]
    np.testing.assert_allclose([t for t, _ in pvd], np.array(run["steps"]) * run["dt"], rtol=1e-15)

    last = run["last_step"]
    pieces = check_pvtu(vtk / f"snapshot-{last:08d}.pvtu")
    assert [os.path.basename(p) for p in pieces] == [f"snapshot-{last:08d}-r{r:04d}.vtu" for r in range(2)]
    meshes = [meshio.read(p) for p in pieces]

    owned_gids, lines, ghosts_seen = [], [], 0
    pos = {}
    for r, m in enumerate(meshes):
        pd = m.point_data
        assert np.all(pd["rank"] == r)
        own = pd["vtkGhostType"] == 0
        state = np.load(tmp_path / f"state-r{r:04d}.npz")
        # owned points, in row order, are exactly this rank's owned elements at the end
        np.testing.assert_array_equal(pd["gid"][own], state["gid"])
        np.testing.assert_array_equal(m.points[own], state["x"])
        np.testing.assert_array_equal(pd["velocity"][own], state["v"])
        np.testing.assert_array_equal(pd["displacement"][own], state["x"] - state["x0"])
        np.testing.assert_array_equal(pd["radius"][own], state["radius"])
        owned_gids.append(pd["gid"][own])
        pos.update(zip(pd["gid"][own].tolist(), m.points[own]))
        ghosts_seen += int((~own).sum())
        g = line_gids(m)
        lines.append(g)
        # the force of every line from its drawn ends, with the textbook ka
        R_ = run["radius"]
        L = np.linalg.norm(np.diff(m.points[m.cells_dict["line"]], axis=1)[:, 0], axis=1)
        want = run["young"] * np.pi * (run["radius_ratio"] * R_) ** 2 / (2 * R_) * (L - 2 * R_)
        np.testing.assert_allclose(m.cell_data_dict["axial_force"]["line"], want, rtol=1e-6,
                                   atol=1e-9 * np.abs(want).max())
    owned_gids = np.concatenate(owned_gids)
    assert np.array_equal(np.sort(owned_gids), np.arange(run["n_elements"]))   # each exactly once
    assert ghosts_seen > 0

    # ghosts are duplicates of elements owned elsewhere, at the same place
    for m in meshes:
        gh = m.point_data["vtkGhostType"] == 1
        for gid, x in zip(m.point_data["gid"][gh].tolist(), m.points[gh]):
            np.testing.assert_array_equal(pos[gid], x)

    lines = np.concatenate(lines)
    assert len(lines) == run["n_bonds"]
    _, lattice_pairs, _ = ordered_lattice([2 * run["radius"] * k] * 3, run["radius"])
    expected = set(map(tuple, np.sort(lattice_pairs, axis=1).tolist()))
    assert set(map(tuple, lines.tolist())) == expected and len(expected) == run["n_bonds"]


# ---------------------------------------------------------------------------- granular content

def test_granular_points_contacts_and_cell_match_the_state(tmp_path):
    """A periodic frictional packing: the points carry the state's arrays by gid; coordination is
    a brute-force count over all pairs (minimum image); the contact lines are the network the HDF5
    contact writer writes; the cell is the box lo..hi."""
    import h5py
    sys.path.insert(0, os.path.join(HERE, "mpi"))
    from contact_writer_run import system
    import pardem
    from pardem.io.contact_writer import ContactWriter, group_name
    sim = pardem.build(pardem.Communicator(), system())
    out = tmp_path / "pv"
    sim.run(20, operations=[ParaViewWriter(out, sim.comm, 20),
                            ContactWriter(tmp_path / "c.h5", trigger=20)])
    e = sim.elements
    n = e.n_owned
    order = np.argsort(e.gid[:n])
    points, pd = read_point_data(out / "snapshot-00000020-r0000.vtu")
    got = np.argsort(pd["gid"])
    assert np.array_equal(pd["gid"][got], np.arange(n))
    for name, arr in (("velocity", e.v), ("spin", e.w), ("orientation", e.q), ("force", e.f),
                      ("torque", e.t), ("radius", e.radius)):
        np.testing.assert_array_equal(pd[name][got], arr[:n][order], err_msg=name)
    np.testing.assert_array_equal(points[got], e.x[:n][order])
    # coordination: brute force over all pairs, minimum image in the periodic box
    x, r = e.x[:n][order], e.radius[:n][order]
    box = sim.cell.length
    i, j = np.triu_indices(n, 1)
    dx = x[j] - x[i]
    dx -= box * np.round(dx / box)
    touch = np.linalg.norm(dx, axis=1) < r[i] + r[j]
    z = np.bincount(i[touch], minlength=n) + np.bincount(j[touch], minlength=n)
    assert z.mean() > 3
    np.testing.assert_array_equal(pd["coordination"][got], z)
    # the contact lines: the HDF5 writer's network, each line from x_i to x_i + branch
    c = meshio.read(out / "contacts-00000020.vtu")
    with h5py.File(tmp_path / "c.h5", "r") as fh:
        ref = {k: v[()] for k, v in fh[group_name(20)].items()}
    cd = {k: v[0] for k, v in c.cell_data.items()}
    np.testing.assert_array_equal(np.stack([cd["gid_i"], cd["gid_j"]], 1), ref["gid"])
    assert len(ref["gid"]) == touch.sum()
    for k in ("normal_force", "tangential_force", "overlap", "sliding"):
        np.testing.assert_array_equal(cd[k], ref[k], err_msg=k)
    lines = c.cells_dict["line"]
    np.testing.assert_array_equal(c.points[lines[:, 0]], x[ref["gid"][:, 0]])
    np.testing.assert_allclose(c.points[lines[:, 1]] - c.points[lines[:, 0]], ref["branch"],
                               rtol=0, atol=1e-18)   # x_i + d - x_i: one rounding of x ~ 1e-2 m
    np.testing.assert_allclose(cd["force_magnitude"],
                               np.linalg.norm(ref["normal_force"] + ref["tangential_force"], axis=1),
                               rtol=1e-15)           # undamped law: the dashpot shares are zero
    # the cell: a hexahedron spanning lo..hi
    b = meshio.read(out / "cell-00000020.vtu")
    assert list(b.cells_dict) == ["hexahedron"]
    np.testing.assert_array_equal(b.points.min(0), sim.cell.lo)
    np.testing.assert_allclose(b.points.max(0), sim.cell.lo + sim.cell.length, rtol=1e-15)
    np.testing.assert_array_equal(b.cell_data["length"][0][0], sim.cell.length)
    for pvd, f in (("contacts.pvd", "contacts-00000020.vtu"), ("cell.pvd", "cell-00000020.vtu")):
        assert read_pvd(out / pvd) == [(pytest.approx(20 * sim.dt, rel=1e-12), f)]


def test_a_tilted_cell_is_written_as_its_parallelepiped():
    """Simple shear tilts the cell: the box written for ParaView has the corners lo + H c (the top
    face shifted by the xy and xz tilts, the far face by yz), not the untilted box."""
    from pardem.engine.periodic_cell import PeriodicCell
    from pardem.io.paraview import cell_mesh
    cell = PeriodicCell((1.0, 2.0, 3.0), (2.0, 4.0, 8.0), (True,) * 3, tilt=(0.5, -0.25, 1.5))
    pts = cell_mesh(cell).points
    # corner (1, 1, 1) of the unit cube: lo + a + b + c with a = (2,0,0), b = (0.5,4,0), c = (-0.25,1.5,8)
    assert np.allclose(pts[6], (1.0 + 2.0 + 0.5 - 0.25, 2.0 + 4.0 + 1.5, 3.0 + 8.0), rtol=0, atol=1e-15)
    assert np.allclose(pts[3], (1.0 + 0.5, 2.0 + 4.0, 3.0), rtol=0, atol=1e-15)     # lo + b
    flat = PeriodicCell((1.0, 2.0, 3.0), (2.0, 4.0, 8.0), (True,) * 3)
    assert np.array_equal(cell_mesh(flat).points[6], (3.0, 6.0, 11.0))
