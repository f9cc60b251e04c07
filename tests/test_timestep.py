"""Critical time step (pardem.physics.timestep), docs/physics.md section 10.

The stiffness matrix K of small bonded lattices (with and without plates) is built by central finite
differences of the kernel forces and moments over all 6N degrees of freedom (rotations as world-frame
rotation vectors), and the damping matrix C by differences over velocities. Then:

* K is symmetric and has exactly the 6 rigid-body zero modes;
* undamped: dt_c from eigen_bound/critical_time_step is <= the true Verlet limit 2 / sqrt(lambda_max
  (M^-1/2 K M^-1/2)) and not absurdly conservative (> 0.3 of it); a run just above the true limit
  blows up, a run at dt_c does not;
* damped: the one-step map of the scheme actually used (velocity Verlet whose damping forces see the
  half-step velocity: v+ = v- + dt M^-1 (-K x - C v-), x+ = x + dt v+) has spectral radius <= 1 at
  dt_c(zeta), and a simulation at dt_c(zeta) stays bounded.
"""
import numpy as np
import pytest

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.domains.ordered import ordered_lattice
from pardem.physics import walls
from pardem.physics.timestep import critical_time_step, eigen_bound, max_tau
from pardem.errors import InstabilityError
from pardem.engine.simulation import Simulation
from pardem.engine.state import Elements, Plates
from _util import FakeComm, loads, qmul, quat

R = 1e-3
MATERIALS = {
    "isotropic": dict(young=1e9, radius_ratio=0.5),
    "thick": dict(young=1e8, radius_ratio=1.0),
    # W's calibrated set: stiff thin L bonds, soft thick R and T bonds
    "W": dict(young=(1.1072e11, 7.73e8, 7.73e8), radius_ratio=(0.33, 1.14, 1.14)),
}


def lattice(material, edge=3, damping=0.0, random_radii=False):
    pos, pairs, frame = ordered_lattice([edge * 2 * R] * 3, R)
    radii = R
    if random_radii:   # heterogeneous masses and inertias on the same grid
        radii = R * np.random.default_rng(0).uniform(0.7, 1.3, len(pos))
    e = Elements.from_spheres(pos, radii, 1000.0)
    b = make_bonds(e, pairs, BeamMaterial(poisson=0.3, damping=damping, **MATERIALS[material]), frame)
    return e, b


def touching_plates(e, b):
    """Plates on both x faces, overlapping the outer elements by 1e-4 R, stiffness = mean ka."""
    lo = e.x[:, 0].min() - e.radius[np.argmin(e.x[:, 0])] + 1e-4 * R
    hi = e.x[:, 0].max() + e.radius[np.argmax(e.x[:, 0])] - 1e-4 * R
    return Plates.pair(0, lo, hi, 0.0, float(np.mean(b.ka)))


def generalised_forces(e, b, plates):
    f, t, _ = loads(b, e)
    if plates is not None:
        normals, offsets, velocities = plates.planes(0.0)
        walls.compute(plates.law, e, normals, offsets, velocities, e.wall_h, 1e-9, plates.wall_force)
        f = e.f.copy()
    return np.concatenate([f, t], axis=1).ravel()


def stiffness_and_damping(e, b, plates=None):
    """K = -dG/du and C = -dG/du' over the 6N DOFs (x, rotation vector) per element, at rest."""
    n = e.n_total
    K = np.zeros((6 * n, 6 * n))
    C = np.zeros((6 * n, 6 * n))
    x_ref, q_ref = e.x.copy(), e.q.copy()
    hx, hr = 1e-7 * R, 1e-7
    for k in range(n):
        for d in range(6):
            g = []
            for s in (1.0, -1.0):
                e.x[:], e.q[:] = x_ref, q_ref
                if d < 3:
                    e.x[k, d] += s * hx
                else:
                    rv = np.zeros(3)
                    rv[d - 3] = s * hr
                    e.q[k] = qmul(quat(rv), q_ref[k])
                e.refresh_rotations()
                g.append(generalised_forces(e, b, plates))
            K[:, 6 * k + d] = -(g[0] - g[1]) / (2 * (hx if d < 3 else hr))
    e.x[:], e.q[:] = x_ref, q_ref
    e.refresh_rotations()
    g0 = generalised_forces(e, b, plates)
    for k in range(n):
        for d in range(6):
            (e.v if d < 3 else e.w)[k, d % 3] = 1.0
            C[:, 6 * k + d] = -(generalised_forces(e, b, plates) - g0)
            e.v[:] = 0.0
            e.w[:] = 0.0
    return K, C


def mass_diag(e):
    return np.column_stack([np.repeat(e.mass[:, None], 3, 1), np.repeat(e.inertia[:, None], 3, 1)]).ravel()


def spectral_radius(K, C, md, dt):
    """Largest |eigenvalue| of the linear one-step map on (x, dt v_half)."""
    A = dt**2 * K / md[:, None]
    B = dt * C / md[:, None]
    Id = np.eye(len(md))
    G = np.block([[Id - A, Id - B], [-A, Id - B]])
    return np.abs(np.linalg.eigvals(G)).max()


def bound(e, b, plate_k_per_mass=None):
    pk = np.zeros(e.n_total) if plate_k_per_mass is None else plate_k_per_mass
    return eigen_bound(b.i, b.j, b.L0, b.ka, b.kb, b.kt, e.mass, e.inertia, e.n_owned, pk)


CASES = [("isotropic", False, False), ("thick", False, False), ("W", False, False),
         ("isotropic", True, False), ("W", True, False), ("isotropic", False, True), ("W", False, True)]


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"{c[0]}{'-radii' if c[1] else ''}{'-plates' if c[2] else ''}")
def undamped(request):
    material, random_radii, with_plates = request.param
    e, b = lattice(material, random_radii=random_radii)
    plates = touching_plates(e, b) if with_plates else None
    K, _ = stiffness_and_damping(e, b, plates)
    md = mass_diag(e)
    Ks = K / np.sqrt(np.outer(md, md))
    pk = None
    if plates is not None:
        touch = ((e.x[:, 0] - e.radius < plates.positions[0]) | (e.x[:, 0] + e.radius > plates.positions[1]))
        pk = np.where(touch, plates.stiffness[0] / e.mass, 0.0)
    return dict(e=e, b=b, K=K, Ks=Ks, with_plates=with_plates, dt_c=critical_time_step(bound(e, b, pk)))


def test_stiffness_symmetric_with_rigid_modes(undamped):
    K, Ks = undamped["K"], undamped["Ks"]
    assert np.abs(K - K.T).max() < 1e-7 * np.abs(K).max()
    lam = np.linalg.eigvalsh(0.5 * (Ks + Ks.T))
    assert lam[0] > -1e-7 * lam[-1]
    # free body: 3 translations + 3 rotations; between frictionless x plates: y, z translations and
    # the rotation about x remain
    n_zero = 3 if undamped["with_plates"] else 6
    assert np.all(np.abs(lam[:n_zero]) < 1e-7 * lam[-1])
    assert lam[n_zero] > 1e-5 * lam[-1]


def test_undamped_bound(undamped):
    Ks = undamped["Ks"]
    lam_max = np.linalg.eigvalsh(0.5 * (Ks + Ks.T))[-1]
    dt_true = 2.0 / np.sqrt(lam_max)
    assert undamped["dt_c"] <= dt_true
    assert undamped["dt_c"] > 0.3 * dt_true


def _random_motion(e, rng, speed=1e-3):
    e.v[:] = rng.normal(size=e.v.shape) * speed
    e.w[:] = rng.normal(size=e.w.shape) * speed / R


def test_runs_above_true_limit_blow_up_and_at_dt_c_do_not():
    e, b = lattice("W")
    K, _ = stiffness_and_damping(e, b)
    md = mass_diag(e)
    Ks = K / np.sqrt(np.outer(md, md))
    dt_true = 2.0 / np.sqrt(np.linalg.eigvalsh(0.5 * (Ks + Ks.T))[-1])
    dt_c = critical_time_step(bound(e, b))
    far = lambda: Plates.pair(0, -10.0, 10.0, 0.0, 1.0)
    state = (e.x.copy(), e.q.copy(), e.rot.copy())
    rng = np.random.default_rng(1)
    _random_motion(e, rng)
    kin0 = 0.5 * np.sum(md * np.column_stack([e.v, e.w]).ravel() ** 2)
    sim = Simulation(FakeComm(), e, b, far(), dt_c)
    sim.run(3000)
    assert sim.kinetic_energy() < 50 * kin0
    e.x[:], e.q[:], e.rot[:] = state
    _random_motion(e, rng)
    sim = Simulation(FakeComm(), e, b, far(), 1.05 * dt_true)
    with pytest.raises(InstabilityError):
        sim.run(3000)


DAMPED = [("W", 3, 0.2), ("thick", 3, 0.2), ("W", 3, 0.5), ("thick", 3, 0.5),
          ("W", 3, 1.0), ("thick", 3, 1.0), ("W", 4, 0.5)]


@pytest.mark.parametrize("material,edge,zeta", DAMPED)
def test_damped_bound(material, edge, zeta):
    e, b = lattice(material, edge=edge, damping=zeta)
    K, C = stiffness_and_damping(e, b)
    md = mass_diag(e)
    dt_c = critical_time_step(bound(e, b), max_tau(b))
    # sanity of the linear model: without damping, dt_c(0) is stable
    assert spectral_radius(K, 0 * C, md, critical_time_step(bound(e, b))) < 1 + 1e-6
    # the actual scheme at dt_c(zeta): linear stability, and a real run from random motion
    rho = spectral_radius(K, C, md, dt_c)
    _random_motion(e, np.random.default_rng(2))
    sim = Simulation(FakeComm(), e, b, Plates.pair(0, -10.0, 10.0, 0.0, 1.0), dt_c)
    try:
        sim.run(2000)
        run = "the run stayed bounded"
    except InstabilityError:
        run = f"a run at dt_c blew up by step {sim.step_count}"
    assert rho < 1 + 1e-6 and run.startswith("the run"), (
        f"dt_c(zeta={zeta}) = {dt_c:.4g} s is not a stability bound: spectral radius of the one-step "
        f"map {rho:.4f}; {run}")


# ---------------------------------------------------------------------------------------------
# contacts: the bound FIRE's adaptive step uses (frictionless Hertz and linear springs)

def _contact_case(law_name, n=3, seed=3):
    """A jittered cubic cluster of n^3 spheres of random radii, neighbours overlapping (no cell)."""
    from pardem.engine.contacts import Contacts
    from pardem.engine.granular import simple_cubic
    from pardem.physics.contact_laws import law_params
    from pardem.physics import hertz_mindlin, linear_contact
    rng = np.random.default_rng(seed)
    pos, _ = simple_cubic(n, R, spacing=1.96, jitter=0.02, seed=seed)
    e = Elements.from_spheres(pos, R * rng.uniform(0.97, 1.03, len(pos)), 2500.0)
    params = {"hertz_mindlin": dict(young=7e10, poisson=0.2, friction=0.0),
              "linear": dict(kn=3e6, kt=1e6, friction=0.0)}[law_name]
    law = {"hertz_mindlin": hertz_mindlin, "linear": linear_contact}[law_name]
    c = Contacts(law, law_params(law_name, params), 0.1 * R)
    c.rebuild(e)
    return e, c


def _contact_forces(e, c):
    e.f[:] = 0.0
    e.t[:] = 0.0
    c.history[:] = 0.0
    c.compute(e, 1e-9)
    return e.f.ravel().copy()


@pytest.mark.parametrize("law_name", ["hertz_mindlin", "linear"])
def test_contact_bound_is_above_the_spectrum(law_name):
    """``Contacts.stiffness`` bound >= the largest eigenvalue of M^-1/2 K M^-1/2, with K from central
    differences of the contact kernel's forces (frictionless: translations only), and not absurdly
    conservative; Verlet at 0.5 * 2 / sqrt(bound) conserves the energy while the cluster flies apart."""
    e, c = _contact_case(law_name)
    n = e.n_owned
    assert np.sum(np.sqrt(np.sum((e.x[c.j] - e.x[c.i]) ** 2, axis=1)) < e.radius[c.i] + e.radius[c.j]) > 30
    h = 1e-9 * R
    K = np.zeros((3 * n, 3 * n))
    x0 = e.x.copy()
    for a in range(3 * n):
        e.x[:] = x0
        e.x.ravel()[a] += h
        fp = _contact_forces(e, c)
        e.x[:] = x0
        e.x.ravel()[a] -= h
        fm = _contact_forces(e, c)
        K[:, a] = -(fp - fm) / (2.0 * h)
    e.x[:] = x0
    assert np.allclose(K, K.T, rtol=0, atol=1e-5 * np.abs(K).max())
    m = np.repeat(e.mass[:n], 3)
    lam = np.linalg.eigvalsh(0.5 * (K + K.T) / np.sqrt(np.outer(m, m))).max()
    bound = c.stiffness(e)[0]
    assert lam <= bound * (1.0 + 1e-6)
    assert bound < 5.0 * lam   # block Gershgorin sums every contact's full stiffness: 2.5-4x measured
    dt = 0.5 * 2.0 / np.sqrt(bound)
    e.f[:] = 0.0
    e.t[:] = 0.0
    sim = Simulation(FakeComm(), e, None, None, dt, contacts=c)
    sim.run(0)
    e0 = sim.contact_energy
    sim.run(2000)
    assert sim.contact_energy < 0.5 * e0   # the elastic energy went into motion
    assert sim.contact_energy + sim.kinetic_energy() == pytest.approx(e0, rel=0.04)   # 2 % measured: (omega dt)^2 / 8


def test_contact_bound_of_one_pair_is_exact():
    """Two equal Hertz spheres: the bound 2 k / m with k = 2 E* sqrt(R* delta) is the pair's
    omega^2, k from a difference of the Hertz force 4/3 E* sqrt(R*) delta^1.5."""
    from pardem.engine.contacts import Contacts
    from pardem.physics.contact_laws import law_params
    from pardem.physics import hertz_mindlin
    delta = 1e-4 * R
    e = Elements.from_spheres(np.array([[0.0, 0.0, 0.0], [2 * R - delta, 0.0, 0.0]]), R, 2500.0)
    params = law_params("hertz_mindlin", dict(young=7e10, poisson=0.2, friction=0.0))
    c = Contacts(hertz_mindlin, params, 0.1 * R)
    c.rebuild(e)
    fn = lambda d: 4.0 / 3.0 * params.e_star * np.sqrt(0.5 * R) * d**1.5
    k = (fn(delta * (1 + 1e-6)) - fn(delta * (1 - 1e-6))) / (2e-6 * delta)
    assert c.stiffness(e)[0] == pytest.approx(2.0 * k / e.mass[0], rel=1e-8)
