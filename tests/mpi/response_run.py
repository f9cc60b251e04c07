"""The point-load response of a compressed triangular lattice, for the response tests.

    python response_run.py OUT.npz [--fraction F] [--top free|rigid|fixed] [--friction MU] [--copies KX KY]
    mpiexec -n 2 python response_run.py OUT.npz

Builds ``lattice_case`` (monodisperse spheres on a triangular lattice, rows along x, spacing
``0.999`` diameters: every contact has the same overlap and the lattice is in equilibrium by
symmetry) in a 2D periodic cell, optionally replicates it, makes the layer of
``pardem.protocols.response`` (y opened, rows, friction), and runs ``respond`` without dynamic
snapshots. Rank 0 writes the per-grain ``dM_yy`` [N m] by gid, the reference positions, the
static profile, the force, the loaded gid, the reference and static unbalanced ratios, the mean
contact force and the row spacing.
"""
import argparse
import json

import numpy as np

from pardem.physics.contact_laws import critical_time_step as contact_critical_time_step

from pardem.physics.contact_laws import law_params

from pardem.config import check_deck
from pardem.parallel.communicator import Communicator
from pardem.protocols import response
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from _util import granular_case

R = 0.1e-3
DENSITY = 2500.0
MATERIAL = {"shear_modulus": 30e9, "poisson": 0.2, "restitution": 1.0}


def lattice_case(comm, nx=12, ny=12, spacing=0.999):
    """A triangular lattice of nx x ny spheres of radius R (ny even, rows along x) in a periodic
    2D cell; returns ``(case, row spacing [m])``."""
    a = 2.0 * R * spacing
    h = a * np.sqrt(3.0) / 2.0
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    x = (i + 0.5 * (j % 2) + 0.25) * a
    y = (j + 0.5) * h
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    E = 2.0 * MATERIAL["shear_modulus"] * (1.0 + MATERIAL["poisson"])
    params = {"young": E, "poisson": MATERIAL["poisson"], "friction": 0.0, "restitution": 1.0}
    dt = 0.25 * contact_critical_time_step("hertz_mindlin", law_params("hertz_mindlin", params),
                                           np.array([R]), DENSITY)
    case = granular_case(comm, pos, R, DENSITY, "hertz_mindlin", params, np.zeros(3), np.array([nx * a, ny * h, 0]),
                          dt, 0.1 * R, periodic=(True, True, False), dimension=2)
    return case, h


def deck_for(top="free", fraction=0.01, friction=0.3, copies=(1, 1), force_tolerance=1e-9, points=1):
    return check_deck(response.SCHEMA, {
        "sample": {"n": 144, "radii": [R], "fractions": [1.0], "density": DENSITY},
        "material": MATERIAL, "boundary": {"top": top}, "replicate": {"copies": list(copies)},
        "load": {"fraction": fraction, "friction": friction, "points": points},
        "relax": {"force_tolerance": force_tolerance, "kinetic_tolerance": 1e-20, "max_steps": 60000,
                  "check_every": 100},
        "dynamic": {"times": []}, "output": {"perturbation_vtk": False, "plot": False}})


def run(comm, top="free", fraction=0.01, friction=0.3, copies=(1, 1), points=1):
    """``(result, layer, row spacing)`` of the lattice's response (result on rank 0 only)."""
    case, h = lattice_case(comm)
    deck = deck_for(top, fraction, friction, copies, points=points)
    layer = response.make_layer(comm, case, deck)
    return response.respond(layer, deck), layer, h


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("out")
    p.add_argument("--fraction", type=float, default=0.01)
    p.add_argument("--top", default="free")
    p.add_argument("--friction", type=float, default=0.3)
    p.add_argument("--copies", type=int, nargs=2, default=(1, 1))
    a = p.parse_args()
    comm = Communicator()
    res, layer, h = run(comm, a.top, a.fraction, a.friction, tuple(a.copies))
    if comm.is_root:
        pg = res.pop("_per_grain")
        np.savez(a.out, dM_yy=pg["dM_yy"], y=layer.geometry["y"], dsigma=np.asarray(res["static"]["dsigma_yy"]),
                 meta=json.dumps({"force": res["force"], "loaded_gid": res["loaded_gid"],
                                  "u_ref": res["reference"]["unbalanced"], "u_static": res["static"]["unbalanced"],
                                  "mean_contact_force": res["reference"]["mean_contact_force"], "h": h,
                                  "n": layer.geometry["n_grains"], "bottom_share": res["reactions"]["bottom_share"],
                                  "steps": res["static"]["steps"], "converged": res["static"]["converged"]}))
