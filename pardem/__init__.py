"""pardem: parallel discrete element method for bonded and granular media.

The Python API: build a ``Simulation`` (``bonded_system``, ``granular_system``), add walls
(``add_walls``), loads and constraints (``add_fixes(sim, ...)``, which keeps the loads ``Gravity``,
``ExternalForce`` before the constraints ``Clamp``, ``PrescribedVelocity`` in ``sim.fixes``), a
thermo ``Log``, then ``sim.run(n_steps)``. The same script runs on one
process (``python script.py``) and on several (``mpiexec -n 2 python script.py``): every rank
passes the same global arrays, elements are selected by global id (index in ``positions``).
A cantilever of 11 spheres, clamped at one end and loaded at the other::

    import numpy as np
    import pardem

    comm = pardem.Communicator()
    n, R = 11, 0.01
    x = np.zeros((n, 3)); x[:, 0] = 2 * R * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    material = pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0)
    sim = pardem.bonded_system(comm, x, R, 1000.0, pairs, material, viscous_damping=270.0)
    pardem.add_fixes(sim, pardem.Clamp([0]), pardem.ExternalForce([n - 1], force=(0, 0, -1e-3)))
    sim.run(30000, operations=[pardem.Log(trigger=10000)])

Checkpoints of such a system: ``pardem.save(sim, "state.h5")`` (collective) and
``sim = pardem.load(comm, "state.h5")`` on any number of ranks (bit for bit on the rank count that
wrote it); fixes and operations are the script's objects: add them again after ``load``.

See ``examples/`` (cantilever, drop on a wall, compression test written with the API).

Names are imported on first use (PEP 562), so ``import pardem`` itself is cheap and compiles
nothing; ``from pardem import Simulation`` imports the module that defines it.
"""
import importlib

__version__ = "0.1.0"

# public name -> (module, attribute)
_EXPORTS = {
    "Communicator": ("pardem.parallel.communicator", "Communicator"),
    "Simulation": ("pardem.engine.simulation", "Simulation"),
    "Elements": ("pardem.engine.state", "Elements"),
    "Bonds": ("pardem.engine.state", "Bonds"),
    "Plates": ("pardem.engine.state", "Plates"),
    "BeamMaterial": ("pardem.engine.bonding", "BeamMaterial"),
    "make_bonds": ("pardem.engine.bonding", "make_bonds"),
    "bonded_system": ("pardem.engine.builders", "bonded_system"),
    "granular_system": ("pardem.engine.builders", "granular_system"),
    "critical_time_step": ("pardem.engine.builders", "critical_time_step"),
    "add_fixes": ("pardem.engine.fixes", "add"),
    "Gravity": ("pardem.engine.fixes", "Gravity"),
    "ExternalForce": ("pardem.engine.fixes", "ExternalForce"),
    "Clamp": ("pardem.engine.fixes", "Clamp"),
    "PrescribedVelocity": ("pardem.engine.fixes", "PrescribedVelocity"),
    "Walls": ("pardem.engine.walls", "Walls"),
    "add_walls": ("pardem.engine.walls", "add_walls"),
    "wall_law": ("pardem.engine.walls", "wall_law"),
    "WallParams": ("pardem.physics.walls", "Params"),
    "Log": ("pardem.io.log", "Log"),
    "energies": ("pardem.io.log", "energies"),
    "ordered_lattice": ("pardem.domains.ordered", "ordered_lattice"),
    "compact_packing": ("pardem.domains.compact", "compact_packing"),
    "compact_domain": ("pardem.domains.compact", "compact_domain"),
    "lrt_frame": ("pardem.physics.anisotropy", "lrt_frame"),
    "save": ("pardem.engine.snapshot", "write"),
    "load": ("pardem.engine.snapshot", "load"),
    "granular_build": ("pardem.engine.granular", "build"),
    "granular_write": ("pardem.engine.granular", "write"),
    "granular_restore": ("pardem.engine.granular", "restore"),
    "build_case": ("pardem.protocols.compression", "build_case"),
    "measure": ("pardem.protocols.compression", "measure"),
    "restore_case": ("pardem.protocols.compression", "restore_case"),
    "write_checkpoint": ("pardem.io.checkpoint", "write_checkpoint"),
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name):
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'pardem' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value      # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
