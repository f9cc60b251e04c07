"""STL files of triangle-mesh walls (numpy-stl reads and writes them, ASCII or binary).

``read_stl(path, scale=1.0)`` gives the triangles ``[n_tri, 3, 3]`` float64 [m] (the file's
coordinates times ``scale``, e.g. 1e-3 for a CAD file in mm); ``write_stl(path, triangles)``
writes a binary STL (the facet normals computed from the vertex order). A mesh wall
(``pardem.engine.walls.Mesh``) takes the triangles; the file is read once, on every rank.
"""
import os

import numpy as np


def read_stl(path, scale=1.0):
    """Triangles [n_tri, 3, 3] [m] of STL file ``path`` (ValueError naming the file when it is
    missing, unreadable or empty)."""
    from stl import mesh as stl_mesh
    if not os.path.isfile(path):
        raise ValueError(f"STL file {path!r} does not exist")
    try:
        m = stl_mesh.Mesh.from_file(path)
    except Exception as err:   # numpy-stl raises several kinds on a malformed file
        raise ValueError(f"STL file {path!r} could not be read: {err}") from None
    tris = np.asarray(m.vectors, dtype=np.float64).reshape(-1, 3, 3) * float(scale)
    if tris.shape[0] == 0 or not np.all(np.isfinite(tris)):
        raise ValueError(f"STL file {path!r} holds no finite triangle (got {tris.shape[0]} triangles)")
    return np.ascontiguousarray(tris)


def write_stl(path, triangles):
    """Write ``triangles`` [n_tri, 3, 3] [m] to a binary STL file ``path``."""
    from stl import mesh as stl_mesh
    tris = np.asarray(triangles, dtype=np.float64)
    if tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise ValueError(f"triangles must have shape [n_tri, 3, 3], got {tris.shape}")
    m = stl_mesh.Mesh(np.zeros(tris.shape[0], dtype=stl_mesh.Mesh.dtype))
    m.vectors[:] = tris
    m.update_normals()
    m.save(path)


__all__ = ["read_stl", "write_stl"]
