"""The BOND benchmark case as a deck for the compress case builder (shared by the benchmarks).

Simple cubic lattice of touching spheres, R = 0.25 mm, density 1000 kg/m^3, beam bonds E = 100 MPa,
bond radius = R, Poisson 0.3, no damping; frictionless plates normal to x, fixed at x_min, moving at
-0.05 m/s at x_max (no ramp); dt = 1e-7 s.
"""
from pardem.config import check_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA

R = 0.25e-3
DT = 1e-7


def bond_deck(nx, ny, nz, damping=0.0):
    """Deck of an nx x ny x nz lattice (elements per edge). ``damping``: the bonds' damping ratio
    (0 in the peer case; the compress job's 0.2 measures the damped force loop it runs)."""
    return check_deck(COMPRESS_SCHEMA, {
        "domain": {"box": [nx * 2 * R, ny * 2 * R, nz * 2 * R], "radius": R, "density": 1000.0},
        "bonds": {"young": 100e6, "radius_ratio": 1.0, "poisson": 0.3, "damping": float(damping)},
        "loading": {"axis": "x", "plate_speed": 0.05, "ramp_time": 0.0, "strain": 0.4},
        "run": {"dt": DT},
    })
