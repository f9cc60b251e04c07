"""pardem: parallel discrete element method for bonded and granular media.

The Python API, at one level (HOOMD-blue and Yade style): describe the system (``System`` of
``Particles``, a ``ContactModel``, a ``BondModel``, ``WallModel``, ``Cell``, ``Integration``,
``Decomposition``), ``build`` the ``Simulation``, add loads and constraints (``add_fixes(sim, ...)``:
``Gravity``, ``ExternalForce``, ``Clamp``, ``PrescribedVelocity``), run it with operations (``Log``,
``ParaViewWriter``, ``CheckpointWriter``, ``ContactWriter``) that run when their trigger fires
(``Periodic``, ``At``, ``After``, ``Before``, ``Never``; an int n is ``Periodic(n)``), and
``save`` / ``load`` checkpoints. The same script
runs on one process (``python script.py``) and on several (``mpiexec -n 2 python script.py``):
every rank passes the same global arrays; particle ``k`` of the arrays has global id ``k``.

A cantilever of 11 spheres, clamped at one end and loaded at the other::

    import numpy as np
    import pardem

    comm = pardem.Communicator()
    n, R = 11, 0.01
    x = np.zeros((n, 3)); x[:, 0] = 2 * R * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    material = pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0)
    system = pardem.System(pardem.Particles(x, R, 1000.0), bonds=pardem.BondModel(material, pairs),
                           integration=pardem.Integration(viscous_damping=270.0))
    sim = pardem.build(comm, system)
    pardem.add_fixes(sim, pardem.Clamp([0]), pardem.ExternalForce([n - 1], force=(0, 0, -1e-3)))
    sim.run(30000, operations=[pardem.Log(trigger=10000)])

Checkpoints: ``pardem.save(sim, "state.h5")`` (collective) and ``sim = pardem.load(comm,
"state.h5")`` on any number of ranks (bit for bit on the rank count that wrote it); the file holds
the system's description (``describe(sim)``) and its state. Fixes and operations are the script's
objects: add them again after ``load``.

The test protocols (compression, isotropic, triaxial, biaxial, point-load response, ...) are in
``pardem.protocols`` and their command lines in ``pardem.drivers``; see ``examples/``.

Names are imported on first use (PEP 562), so ``import pardem`` itself is cheap and compiles
nothing; ``from pardem import Simulation`` imports the module that defines it.
"""
from pardem.io import numba_cache  # noqa: F401  first: a writable Numba cache before any kernel is decorated
import importlib

__version__ = "0.1.0"

# public name -> (module, attribute)
_EXPORTS = {
    # the description and the builder
    "System": ("pardem.engine.system", "System"),
    "Particles": ("pardem.engine.system", "Particles"),
    "ContactModel": ("pardem.engine.system", "ContactModel"),
    "BondModel": ("pardem.engine.system", "BondModel"),
    "WallModel": ("pardem.engine.system", "WallModel"),
    "Cell": ("pardem.engine.system", "Cell"),
    "Integration": ("pardem.engine.system", "Integration"),
    "Decomposition": ("pardem.engine.system", "Decomposition"),
    "build": ("pardem.engine.system", "build"),
    "describe": ("pardem.engine.system", "describe"),
    "set_contact_params": ("pardem.engine.system", "set_contact_params"),
    "Simulation": ("pardem.engine.simulation", "Simulation"),
    "Communicator": ("pardem.parallel.communicator", "Communicator"),
    # materials and laws
    "BeamMaterial": ("pardem.engine.bonding", "BeamMaterial"),
    "WallLaw": ("pardem.physics.walls", "Params"),
    "wall_law": ("pardem.engine.walls", "wall_law"),
    "contact_law_params": ("pardem.physics.contact_laws", "law_params"),
    # loads and constraints
    "add_fixes": ("pardem.engine.fixes", "add"),
    "Gravity": ("pardem.engine.fixes", "Gravity"),
    "ExternalForce": ("pardem.engine.fixes", "ExternalForce"),
    "Clamp": ("pardem.engine.fixes", "Clamp"),
    "PrescribedVelocity": ("pardem.engine.fixes", "PrescribedVelocity"),
    # writers and measures
    "Log": ("pardem.io.log", "Log"),
    "ParaViewWriter": ("pardem.io.paraview", "ParaViewWriter"),
    "CheckpointWriter": ("pardem.io.checkpoint_writer", "CheckpointWriter"),
    "ContactWriter": ("pardem.io.contact_writer", "ContactWriter"),
    "energies": ("pardem.io.log", "energies"),
    "critical_time_step": ("pardem.engine.critical_step", "critical_time_step_of"),
    # triggers: when an operation runs
    "Periodic": ("pardem.triggers", "Periodic"),
    "At": ("pardem.triggers", "At"),
    "Never": ("pardem.triggers", "Never"),
    "After": ("pardem.triggers", "After"),
    "Before": ("pardem.triggers", "Before"),
    # checkpoints
    "save": ("pardem.restart", "save"),
    "load": ("pardem.restart", "load"),
    # geometry of domains
    "ordered_lattice": ("pardem.domains.ordered", "ordered_lattice"),
    "compact_packing": ("pardem.domains.compact", "compact_packing"),
    "compact_domain": ("pardem.domains.compact", "compact_domain"),
    "simple_cubic": ("pardem.engine.granular", "simple_cubic"),
    "lrt_frame": ("pardem.physics.anisotropy", "lrt_frame"),
    # particle factories: size distributions (radii [m], by number or by volume), regions,
    # random packings without overlap, insertion and deletion during a run
    # (sim.particles.add / remove are the engine's entry points)
    "Uniform": ("pardem.domains.distributions", "Uniform"),
    "Normal": ("pardem.domains.distributions", "Normal"),
    "LogNormal": ("pardem.domains.distributions", "LogNormal"),
    "Discrete": ("pardem.domains.distributions", "Discrete"),
    "Bidisperse": ("pardem.domains.distributions", "Bidisperse"),
    "BoxRegion": ("pardem.domains.regions", "Box"),
    "CylinderRegion": ("pardem.domains.regions", "Cylinder"),
    "SphereRegion": ("pardem.domains.regions", "Sphere"),
    "random_pack": ("pardem.domains.packing", "random_pack"),
    "Insert": ("pardem.engine.insertion", "Insert"),
    "Delete": ("pardem.engine.insertion", "Delete"),
    # walls: prescribed motions, servo, cylinders, triangle meshes (STL)
    "Cylinder": ("pardem.engine.walls", "Cylinder"),
    "Mesh": ("pardem.engine.walls", "Mesh"),
    "Servo": ("pardem.engine.walls", "Servo"),
    "ConstantMotion": ("pardem.physics.wall_motion", "Constant"),
    "Ramp": ("pardem.physics.wall_motion", "Ramp"),
    "Sinusoid": ("pardem.physics.wall_motion", "Sinusoid"),
    "MotionTable": ("pardem.physics.wall_motion", "Table"),
    "read_stl": ("pardem.io.stl", "read_stl"),
    "write_stl": ("pardem.io.stl", "write_stl"),
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
