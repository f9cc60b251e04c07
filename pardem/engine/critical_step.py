"""The critical time step of velocity Verlet for a ``Simulation``: bonds, walls, contacts, damping."""
import math

import numpy as np

from pardem.engine.state import Bonds
from pardem.physics.contact_laws import LAWS, critical_time_step
from pardem.physics.timestep import critical_time_step as verlet_critical_step
from pardem.physics.timestep import eigen_bound, max_tau


def critical_time_step_of(sim, walls=None, contacts_of=None):
    """Critical time step [s] of ``sim`` (collective: every rank gets the same value).

    Bonds and walls: ``sqrt(tau^2 + 4 / omega_max^2) - tau`` with ``omega_max^2`` the block
    Gershgorin bound of ``pardem.physics.timestep.eigen_bound`` (each element also feels the wall
    stiffness ``walls.stiffness(R) / m``, as if it touched a wall) and ``tau`` the largest bond
    damping time; contacts: the law's step for the radii and density; global viscous damping C:
    ``2 / C``. ``walls`` default ``sim.plates``. ``inf`` when nothing is stiff.
    ``contacts_of``: (ContactModel, radii [n] [m], density [kg/m^3]) of the whole system (default:
    the smallest sphere and mass of ``sim``, reduced over ranks).
    """
    comm, e, b = sim.comm, sim.elements, sim.bonds
    if b is None:
        b = Bonds.empty()
    if walls is None and callable(getattr(sim.plates, "stiffness", None)):
        walls = sim.plates
    n = e.n_owned
    dt_c = math.inf
    if walls is not None or comm.any(b.n > 0):
        r_max = float(comm.max(float(e.radius[:n].max()) if n else 0.0))
        k_wall = walls.stiffness(r_max) if walls is not None else 0.0
        lam = eigen_bound(b.i, b.j, b.L0, b.ka, b.kb, b.kt, e.mass, e.inertia, n,
                          np.ascontiguousarray(k_wall / e.mass))
        dt_c = verlet_critical_step(comm.max(float(lam)), comm.max(max_tau(b)))
    if sim.contacts is not None:
        if contacts_of is not None:
            model, radii, density = contacts_of
            dt_c = min(dt_c, critical_time_step(model.law, sim.contacts.params, radii, density))
        else:
            r_min = float(comm.min(float(e.radius[:n].min()) if n else np.inf))
            dt_c = min(dt_c, critical_time_step(contact_law_name(sim.contacts), sim.contacts.params,
                                                np.array([r_min]), sim.density))
    if sim.viscous_damping > 0.0:
        dt_c = min(dt_c, 2.0 / sim.viscous_damping)   # C dt < 2 (pardem.physics.viscous_damping)
    return float(dt_c)


def contact_law_name(contacts):
    """The registry name of a ``Contacts``' law."""
    for name, module in LAWS.items():
        if contacts.law is module:
            return name
    raise ValueError(f"unknown contact law module {contacts.law!r}")


__all__ = ["critical_time_step_of", "contact_law_name"]
