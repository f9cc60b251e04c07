"""The one description of a system (``pardem.engine.system.System``), its builder and its restore.

* the model part of a description survives JSON (``to_dict`` / ``from_dict``) unchanged;
* ``describe`` follows what a run changes (contact parameters, damping) and a checkpoint written
  afterwards restores those, continuing bit for bit against the uninterrupted run;
* bad descriptions are refused with one ``ValueError`` naming the field, before any work, and a
  property-based test over the builder's arguments finds nothing but ``ValueError`` / ``TypeError``
  with a message.
"""
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pardem
from pardem import restart
from pardem.engine.system import describe, set_contact_params
from pardem.errors import InstabilityError

R, RHO = 1e-3, 2500.0
HERTZ = {"young": 7e10, "poisson": 0.25, "friction": 0.3}


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def gas(n=4, seed=3):
    """A loose cubic array of n^3 grains, slightly jittered, with random velocities and spins."""
    rng = np.random.default_rng(seed)
    g = (np.arange(n) + 0.5) * 2.2 * R
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    x += rng.uniform(-0.05 * R, 0.05 * R, x.shape)
    return x, n * 2.2 * R, rng.normal(scale=0.05, size=x.shape), rng.normal(scale=20.0, size=x.shape)


def granular(comm, **integration):
    x, edge, v, w = gas()
    system = pardem.System(pardem.Particles(x, R, RHO, velocities=v, angular_velocities=w),
                           contacts=pardem.ContactModel("hertz_mindlin", dict(HERTZ)),
                           cell=pardem.Cell(np.zeros(3), np.full(3, edge), servo=(1e5, 1e-7, 10.0)),
                           integration=pardem.Integration(**{"dt_fraction": 0.2, **integration}),
                           decomposition=pardem.Decomposition(slab_axis=0))
    return system


def test_the_model_survives_json():
    mat = pardem.BeamMaterial(young=(1e8, 5e6, 1e6), radius_ratio=0.5, poisson=0.3, damping=0.1,
                              tensile_strength=1e6)
    walls = pardem.WallModel([[0, 0, 1]], [[0, 0, 0]], pardem.wall_law("hertz", young=1e8, poisson=0.3),
                             velocities=[0, 0, 0.1])
    system = pardem.System(None, contacts=pardem.ContactModel("linear", {"kn": 1e3, "kt": 1e3}),
                           bonds=pardem.BondModel(mat, frame=pardem.lrt_frame(30.0)), walls=walls,
                           cell=pardem.Cell((0, 0, -1), (1, 2, 3), (True, False, False), (1.0, 0, 0)),
                           integration=pardem.Integration(dt=1e-7, viscous_damping=3.0, check_every=7),
                           decomposition=pardem.Decomposition(slab_axis=1, skin=1e-4, balance_every=9))
    text = json.dumps(system.to_dict())
    back = pardem.System.from_dict(json.loads(text))
    assert back.to_dict() == system.to_dict()
    assert back.bonds.material == mat                      # tuples come back as tuples
    assert back.walls.law == walls.law
    with pytest.raises(ValueError, match="not a system description"):
        pardem.System.from_dict({"kind": "deck"})


def test_describe_follows_the_run_and_the_restore_reads_it(comm, tmp_path):
    """Friction and damping changed between runs are in the checkpoint: the restored run
    continues bit for bit (an old model, e.g. the build's friction, would change the forces)."""
    sim = pardem.build(comm, granular(comm, viscous_damping=50.0))
    sim.run(100)
    assert describe(sim).contacts.params["friction"] == 0.3
    set_contact_params(sim, {**HERTZ, "friction": 0.6})
    sim.viscous_damping = 0.0
    model = describe(sim)
    assert model.contacts.params["friction"] == 0.6 and model.integration.viscous_damping == 0.0
    assert model.cell.state is not None and model.particles is None
    path = str(tmp_path / "s.h5")
    pardem.save(sim, path)
    back = pardem.load(comm, path)
    assert back.contacts.params == sim.contacts.params and back.viscous_damping == 0.0
    sim.run(200)
    back.run(200)
    for k in ("x", "v", "w", "f", "t"):
        assert np.array_equal(getattr(sim.elements, k), getattr(back.elements, k)), k
    assert np.array_equal(sim.contacts.history, back.contacts.history)
    assert np.array_equal(sim.cell.length, back.cell.length)
    # the restored run's description is the model it was saved with
    assert describe(back).to_dict() == describe(sim).to_dict()


def test_a_protocol_checkpoint_is_refused_by_load(comm, tmp_path):
    from pardem.io.checkpoint import CheckpointError
    from pardem.protocols.compression import build_case, checkpoint_payload
    from pardem.protocols.compression_deck import COMPRESS_SCHEMA
    from pardem.config import check_deck
    from pardem.io import checkpoint
    deck = check_deck(COMPRESS_SCHEMA, {"domain": {"box": [0.002, 0.002, 0.002], "radius": 0.25e-3}})
    case = build_case(comm, deck, steps=2)
    path = str(tmp_path / "c.h5")
    groups, series, attrs = checkpoint_payload(case)
    checkpoint.write_checkpoint(path, comm, groups, series, attrs)
    with pytest.raises(CheckpointError, match="not a checkpoint of a pardem System"):
        restart.load(comm, path)


@pytest.mark.parametrize("change, message", [
    (lambda s: setattr(s, "particles", None), "System.particles must be a pardem Particles"),
    (lambda s: setattr(s.particles, "positions", [[0, 0]]), r"positions must be finite with shape \(n, 3\)"),
    (lambda s: setattr(s.particles, "positions", [[0, 0, math.nan]]), "positions must be finite"),
    (lambda s: setattr(s.particles, "radii", [R, R]), r"radii must be a scalar or have shape \(64,\)"),
    (lambda s: setattr(s.particles, "density", -1.0), "density must be a finite number > 0"),
    (lambda s: setattr(s.particles, "velocities", np.zeros((3, 3))), r"velocities must be finite with shape \(64, 3\)"),
    (lambda s: setattr(s, "contacts", "hertz"), "System.contacts must be a ContactModel"),
    (lambda s: setattr(s.contacts, "law", "hooke"), "contact law 'hooke': expected one of"),
    (lambda s: setattr(s.integration, "dt_fraction", 0.0), r"dt_fraction must be a number in \(0, 1\]"),
    (lambda s: setattr(s.integration, "dt", 1.0), "Integration.dt = 1 s is above the critical time step"),
    (lambda s: setattr(s.integration, "viscous_damping", -1.0), r"viscous_damping = .*expected a number in \[0, inf\) \[1/s\]"),
    (lambda s: setattr(s.integration, "viscous_damping", math.nan), r"viscous_damping = .*expected a number in \[0, inf\) \[1/s\]"),
    (lambda s: setattr(s.integration, "check_every", 2.5), "check_every must be an integer >= 1"),
    (lambda s: setattr(s.decomposition, "slab_axis", 3), "slab_axis = 3: expected 0, 1, 2 or 'auto'"),
    (lambda s: setattr(s.decomposition, "skin", 0.0), "skin must be a finite number > 0 \\[m\\]"),
    (lambda s: setattr(s, "dimension", 4), "System.dimension = 4: expected 2"),
    (lambda s: setattr(s, "bonds", pardem.BondModel(pardem.BeamMaterial(1e8, 0.5, 0.3, 0.0), [[0, 1]])),
     "bonds across a periodic boundary are not supported"),
])
def test_bad_descriptions_are_refused_naming_the_field(comm, change, message):
    system = granular(comm)
    change(system)
    with pytest.raises(ValueError, match=message):
        pardem.build(comm, system)


@pytest.mark.parametrize("ratio", [1e-300, 1e-80, 1e80, 1e300])
def test_a_bond_section_outside_the_float_range_is_refused(comm, ratio):
    """r**4 underflows to 0 (or overflows) near r / R ~ 1e-77 (1e77): a bond of zero or infinite
    stiffness would turn the first step's damping into NaN, so the builder refuses it."""
    x = np.array([[0.0, 0.0, 0.0], [2 * R, 0.0, 0.0]])
    system = pardem.System(pardem.Particles(x, R, RHO),
                           bonds=pardem.BondModel(pardem.BeamMaterial(1e6, ratio, 0.0, 1.0), [[0, 1]]))
    with pytest.raises(ValueError, match="BeamMaterial.young, radius_ratio: a bond's .* stiffness is"):
        pardem.build(comm, system)


@pytest.mark.parametrize("radius, density", [(1e-110, 1e3), (1e-70, 1e3), (1e100, 1e3), (1e-3, 1e-300)])
def test_a_mass_or_inertia_outside_the_float_range_is_refused(comm, radius, density):
    """r^3 (mass) or r^5 (inertia) underflows to 0 or overflows: the kicks would divide by them."""
    system = pardem.System(pardem.Particles([[0.0, 0.0, 0.0]], radius, density),
                           integration=pardem.Integration(dt=1e-6))
    with pytest.raises(ValueError, match="radii and density give element 0 a mass of .* both must be finite and normal"):
        pardem.build(comm, system)


def test_a_row_blown_to_nan_stops_the_run_as_unstable(comm):
    """A non-finite position met by the contact list's rebuild is an instability (exit code and
    last good checkpoint), not a ValueError from the binning."""
    sim = pardem.build(comm, granular(comm, check_every=1000))
    sim.run(2)
    sim.elements.x[5] = np.nan
    sim.elements.v[:] = 0.0
    with pytest.raises(InstabilityError, match="NaN or speed above the limit"):
        sim.contacts.vl.builds = 0      # the next step rebuilds
        sim.run(1)


def test_a_system_without_anything_stiff_needs_a_time_step(comm):
    with pytest.raises(ValueError, match="nothing in this system is stiff"):
        pardem.build(comm, pardem.System(pardem.Particles([[0, 0, 0]], R, RHO)))
    sim = pardem.build(comm, pardem.System(pardem.Particles([[0, 0, 0]], R, RHO),
                                           integration=pardem.Integration(dt=1e-3)))
    pardem.add_fixes(sim, pardem.Gravity((0, 0, -10.0)))
    sim.run(100)
    # free fall under velocity Verlet is exact for a constant force: z = -g t^2 / 2
    assert sim.elements.x[0, 2] == pytest.approx(-0.5 * 10.0 * (100 * 1e-3) ** 2, rel=1e-12)


finite = st.floats(allow_nan=True, allow_infinity=True, width=64)
anything = st.one_of(st.none(), st.booleans(), st.integers(-3, 3), finite, st.text(max_size=3),
                     st.lists(finite, max_size=4), st.lists(st.lists(finite, max_size=4), max_size=3))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(positions=st.one_of(anything, st.lists(st.lists(st.floats(-1e-2, 1e-2), min_size=3, max_size=3),
                                              min_size=1, max_size=5)),
       radii=st.one_of(anything, st.floats(1e-4, 2e-3)), density=st.one_of(anything, st.floats(1.0, 1e4)),
       params=st.dictionaries(st.sampled_from(["young", "poisson", "friction", "restitution", "E", "kn"]),
                              st.one_of(finite, st.floats(0.01, 1e9)), max_size=4),
       dt=st.one_of(st.none(), anything), fraction=st.one_of(anything, st.floats(0.01, 1.0)),
       damping=st.one_of(anything, st.floats(0.0, 10.0)), axis=st.one_of(anything, st.sampled_from([0, 1, 2, "auto"])),
       skin=st.one_of(st.none(), anything), dimension=st.one_of(anything, st.sampled_from([2, 3])))
def test_the_builder_raises_nothing_but_clear_errors(positions, radii, density, params, dt, fraction, damping,
                                                    axis, skin, dimension):
    system = pardem.System(pardem.Particles(positions, radii, density),
                           contacts=pardem.ContactModel("hertz_mindlin", params),
                           cell=pardem.Cell(np.full(3, -0.02), np.full(3, 0.04)),
                           integration=pardem.Integration(dt=dt, dt_fraction=fraction, viscous_damping=damping),
                           decomposition=pardem.Decomposition(slab_axis=axis, skin=skin), dimension=dimension)
    try:
        pardem.build(pardem.Communicator(), system)
    except (ValueError, TypeError) as err:
        assert str(err).strip(), type(err)


def test_deep_overlaps_are_refused_unless_allowed(comm):
    """Two unbonded spheres overlapping by 0.8 R (a radius given as a diameter looks like this)
    are refused before any work; a gas a servo will separate may ask for it."""
    x = [[0.0, 0.0, 0.0], [1.2 * R, 0.0, 0.0]]
    law = pardem.ContactModel("hertz_mindlin", dict(HERTZ))
    with pytest.raises(ValueError, match="overlap by more than 0.5 of the smaller radius"):
        pardem.build(comm, pardem.System(pardem.Particles(x, R, RHO), contacts=law))
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, RHO, allow_overlaps=True), contacts=law))
    assert sim.n_elements == 2
    with pytest.raises(ValueError, match="coincide"):
        pardem.build(comm, pardem.System(pardem.Particles([[0, 0, 0], [0, 0, 0]], R, RHO, allow_overlaps=True),
                                         contacts=law))
    with pytest.raises(ValueError, match="allow_overlaps must be True or False"):
        pardem.build(comm, pardem.System(pardem.Particles(x, R, RHO, allow_overlaps="yes"), contacts=law))
