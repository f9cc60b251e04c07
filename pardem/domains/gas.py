"""A random polydisperse gas of spheres (or disks in the plane z = 0) in a periodic cell.

``gas`` draws non-overlapping centres by random sequential addition on a cell grid, with the
radii of ``species_radii`` (a seeded random order), from ``numpy.random.default_rng(seed)``: a
seed gives the same gas on any machine. Pure NumPy; the protocols build it on rank 0 and
broadcast it (``pardem.protocols.stages.build_gas``).
"""
import numpy as np


def species_radii(n, radii, fractions, rng):
    """[n] radii: ``round(n f_k)`` of species k (the last takes the remainder), in random order."""
    f = np.asarray(fractions, dtype=float)
    f = f / f.sum()
    counts = np.floor(n * f + 0.5).astype(int)
    counts[-1] = n - counts[:-1].sum()
    r = np.repeat(np.asarray(radii, dtype=float), counts)
    return r[rng.permutation(n)]


def gas(n, radii, fractions, solid_fraction, seed, dim=3, aspect=1.0):
    """Random non-overlapping centres [n, 3] in a periodic box, the radii [n] and the edges [3] [m].

    Random sequential addition: each sphere is drawn uniformly until it overlaps none of those
    placed (checked in the 27 neighbouring cells of a grid of cell size >= 2 R_max). ``dim = 2``:
    disks in a periodic rectangle at the area fraction ``solid_fraction``, centres at z = 0 (9
    cells; the z edge is then unused). ``aspect``: the y edge over the others (1: a cube or square).
    """
    rng = np.random.default_rng(seed)
    r = species_radii(n, radii, fractions, rng)
    scale = np.array([1.0, aspect, 1.0])
    if dim == 2:
        edge = np.sqrt(np.sum(np.pi * r**2) / solid_fraction / aspect) * scale
    else:
        edge = (np.sum(4.0 / 3.0 * np.pi * r**3) / solid_fraction / aspect) ** (1.0 / 3.0) * scale
    m = np.maximum(1, (edge // (2.0 * r.max())).astype(int))
    size = edge / m
    grid = {}
    pos = np.zeros((n, 3))
    zs = (0,) if dim == 2 else (-1, 0, 1)
    for k in range(n):
        for _ in range(100000):
            x = np.zeros(3)
            x[:dim] = rng.uniform(0.0, edge[:dim], dim)
            c = np.floor(x / size).astype(int) % m
            near = [q for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in zs
                    for q in grid.get(((c[0] + dx) % m[0], (c[1] + dy) % m[1], (c[2] + dz) % m[2]), ())]
            if near:
                d = pos[near] - x
                d[:, :dim] -= edge[:dim] * np.round(d[:, :dim] / edge[:dim])
                if np.any(np.einsum("ij,ij->i", d, d) < (r[near] + r[k]) ** 2):
                    continue
            pos[k] = x
            grid.setdefault(tuple(c), []).append(k)
            break
        else:
            raise RuntimeError(f"random sequential addition: no room for sphere {k} of {n} at solid "
                               f"fraction {solid_fraction}")
    return pos, r, edge


__all__ = ["gas", "species_radii"]
