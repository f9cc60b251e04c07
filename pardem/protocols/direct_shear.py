"""Direct shear box test of frictional spheres (Jewett / Casagrande box; docs/physics.md, walls).

Geometry (``walls``): a box ``L x W`` [m] in x, y. The floor (z = 0) and the two side planes
y = 0, y = W are static planes; the lid is a plane under a force servo (``pardem.engine.walls.Servo``)
holding the normal stress ``sigma_n``; the walls across the shear direction x are triangle meshes
(``pardem.engine.walls.Mesh``, each a rectangle of two triangles): the lower half box's two
(x = 0 and x = L, z in [0, z_split]) are static, the upper half box's two (z above z_split) move
along +x at ``shear.velocity`` from the start of the shear; two horizontal ledges at z_split, the
thick walls' faces of a real box (beyond x = L, static; before x = 0, moving with the upper box),
keep the grains from pouring out of the box through the openings the shear uncovers (a ``wall_motion.Table``: at rest
during the preparation). Every wall is frictionless (one law per wall set), so the x force the
grains exert on the upper half box is the shear resistance of the plane z = z_split alone, and the
lid's force is the normal force on that plane (no gravity).

Protocol:

1. **Preparation** (``preparation.steps`` steps): a random polydisperse gas
   (``pardem.domains.packing.random_pack``, radii uniform in ``R (1 +- dispersity)``) is
   compressed by the lid's servo to ``sigma_n`` with frictionless grains (``preparation.friction``,
   default 0: a dense sample) and global viscous damping.
2. **Shear**: the grains' friction ``contacts.friction`` is switched on, the damping removed, and
   the upper half box moves at ``shear.velocity`` until ``shear.displacement`` (a fraction of L).

Measures (``sample``): the horizontal displacement ``d`` of the upper box, the shear force
``F_s`` [N] (minus the x force of the grains on the upper box's meshes), the lid's normal force
``F_n`` [N], ``tau = F_s / (L W)``, ``sigma = F_n / (L W)`` [Pa], the friction coefficient
``F_s / F_n`` (the nominal area cancels) and the lid's rise ``dz`` [m] since the shear started
(dilation positive). ``summary``: peak and residual (mean over the last quarter of the
displacement) friction coefficients, dilation at peak and at the end, the servo's normal stress
error over the shear.
"""
import math

import numpy as np

from pardem.config import DeckError, Field, Schema, number, positive
from pardem.domains import distributions, packing, regions
from pardem.engine import granular
from pardem.engine.system import (ContactModel, Decomposition, Integration, Particles, System, WallModel,
                                  set_contact_params)
from pardem.engine.walls import Mesh, Servo, Walls, wall_law
from pardem.errors import StepLimit
from pardem.physics import wall_motion
from pardem.physics.contact_laws import critical_time_step, law_params
from pardem.protocols import output_deck
from pardem.protocols.granular_output import CHECKPOINT_SECTION, RowSampler, run_section

AXES = "xyz"
TOP = 1                  # the lid's plane row (planes: floor, lid, y = 0, y = W)
LOWER, UPPER = (4, 5, 6), (7, 8, 9)    # wall rows of the lower and upper half boxes' meshes


SCHEMA = Schema({
    "sample": {
        "n": Field(300, number(lo=20, lo_open=False, integer=True), "number of spheres"),
        "radius": Field(1e-3, positive(), "mean sphere radius R [m]"),
        "dispersity": Field(0.2, number(0.0, 0.5, lo_open=False), "radii uniform in R (1 +- dispersity)"),
        "density": Field(2500.0, positive(), "grain density [kg/m^3]"),
        "box": Field(12.0, number(lo=6.0, lo_open=False), "box edges L = W in mean radii R"),
        "gas_fraction": Field(0.3, number(0.05, 0.35, hi_open=False), "solid fraction of the initial gas"),
        "seed": Field(1, number(lo=0, lo_open=False, integer=True), "seed of the radii and positions"),
    },
    "contacts": {
        "young": Field(5e7, positive(), "grains' (and walls') Young modulus [Pa]"),
        "poisson": Field(0.3, number(-1.0, 0.5), "Poisson ratio"),
        "friction": Field(0.5, number(lo=0.0, lo_open=False), "grain-grain Coulomb friction of the shear"),
        "restitution": Field(0.5, number(0.0, 1.0, hi_open=False), "normal restitution"),
    },
    "preparation": {
        "friction": Field(0.0, number(lo=0.0, lo_open=False), "grain friction while compressing (0: dense)"),
        "viscous_damping": Field(200.0, number(lo=0.0, lo_open=False), "global damping [1/s]"),
        "steps": Field(15000, number(lo=1, lo_open=False, integer=True), "steps of the preparation"),
    },
    "shear": {
        "normal_stress": Field(1e4, positive(), "sigma_n held by the lid's servo [Pa]"),
        "velocity": Field(0.05, positive(), "speed of the upper half box [m/s]"),
        "displacement": Field(0.15, number(0.0, 0.4), "final displacement of the upper box / L"),
        "gain_fraction": Field(0.02, number(0.0, 1.0),
                               "servo gain as a fraction of its one-contact stability bound"),
        "max_speed": Field(0.5, positive(), "the lid's largest speed [m/s]"),
    },
    "run": run_section("critical (Rayleigh) step of the smallest sphere", "auto = 0.1 x sample.radius"),
    "checkpoint": CHECKPOINT_SECTION,
    "output": output_deck.output_section(samples=output_deck.samples("rows of the shear series")),
})

COLUMNS = ("step", "time", "displacement", "shear_force", "normal_force", "tau", "sigma_n", "friction",
           "dilation", "kinetic_energy")
UNITS = ("1", "s", "m", "N", "N", "Pa", "Pa", "1", "m", "J")
DESCRIPTION = ("pardem direct shear series: one row per sample of the shear: displacement of the upper "
               "box, shear and normal forces, tau and sigma_n over the nominal area, tau/sigma_n, the "
               "lid's rise since the shear started (dilation positive), kinetic energy")


def contact_params(deck, friction):
    c = deck["contacts"]
    return {"young": c["young"], "poisson": c["poisson"], "friction": float(friction),
            "restitution": c["restitution"]}


def time_step(deck):
    """``run.dt_fraction`` of the critical step of the smallest sphere [s]."""
    s = deck["sample"]
    prm = law_params("hertz_mindlin", contact_params(deck, deck["contacts"]["friction"]))
    r_min = s["radius"] * (1.0 - s["dispersity"])
    return deck["run"]["dt_fraction"] * critical_time_step("hertz_mindlin", prm, np.array([r_min]), s["density"])


def geometry(deck):
    """``(L, h0, z_split, z_top)`` [m]: the box edge, the gas's height, the split plane (half the
    height of the sample at a solid fraction of 0.6) and the top of the meshes."""
    s = deck["sample"]
    L = s["box"] * s["radius"]
    d = s["dispersity"]
    v = s["n"] * 4.0 / 3.0 * math.pi * s["radius"] ** 3 * (1.0 + d * d)     # <r^3> of uniform radii
    h0 = v / (s["gas_fraction"] * L * L)
    return L, h0, 0.5 * v / (0.6 * L * L), h0 + 2.0 * s["radius"]


def rectangle(x, y0, y1, z0, z1):
    """The rectangle x = const, y in [y0, y1], z in [z0, z1] as two triangles [2, 3, 3] [m]."""
    a, b, c, e = (x, y0, z0), (x, y1, z0), (x, y1, z1), (x, y0, z1)
    return np.array([[a, b, c], [a, c, e]], dtype=np.float64)


def ledge(z, x0, x1, y0, y1):
    """The horizontal rectangle z = const, x in [x0, x1], y in [y0, y1] as two triangles [2, 3, 3] [m]."""
    a, b, c, e = (x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)
    return np.array([[a, b, c], [a, c, e]], dtype=np.float64)


def shear_start(deck):
    """The time [s] the shear starts: the end of the preparation."""
    return deck["preparation"]["steps"] * time_step(deck)


def shear_steps(deck):
    L = deck["sample"]["box"] * deck["sample"]["radius"]
    return int(math.ceil(deck["shear"]["displacement"] * L / (deck["shear"]["velocity"] * time_step(deck))))


def build(comm, deck):
    """The gas in the box, the lid's servo at sigma_n, frictionless grains and damping (collective)."""
    s, c, sh = deck["sample"], deck["contacts"], deck["shear"]
    L, h0, zs, ztop = geometry(deck)
    R = s["radius"]
    dist = distributions.Uniform(R * (1.0 - s["dispersity"]), R * (1.0 + s["dispersity"]))
    try:
        cloud = packing.random_pack(regions.Box((0.0, 0.0, 0.0), (L, L, h0)), dist, n=s["n"], seed=s["seed"])
    except ValueError as err:
        raise DeckError(f"sample: {err}") from None
    if not cloud.complete:
        raise DeckError(f"sample.gas_fraction = {s['gas_fraction']}: only {cloud.n} of {s['n']} spheres "
                        "fit in the gas; lower it")
    dt = time_step(deck)
    law = wall_law("hertz", young=c["young"], poisson=c["poisson"], restitution=c["restitution"], friction=0.0)
    t0, T = shear_start(deck), shear_steps(deck) * dt
    # at rest until the shear starts, then at the shear velocity (held after t0 + 2 T: past the end)
    move = wall_motion.Table([0.0, t0, t0 + 2.0 * T], [[0, 0, 0], [0, 0, 0], [2.0 * T * sh["velocity"], 0, 0]])
    m = 2.0 * R       # the meshes reach past the side planes
    D = sh["displacement"] * L + m
    # the walls of a real box are thick: the lower box's wall top (a ledge at z_split beyond x = L)
    # carries the grains the upper box moves past it, the upper box's wall bottom (a ledge before
    # x = 0, moving with it) covers the lower box's grains it uncovers; without them grains pour out
    meshes = [Mesh(rectangle(0.0, -m, L + m, -m, zs), name="lower x=0"),
              Mesh(rectangle(L, -m, L + m, -m, zs), name="lower x=L"),
              Mesh(ledge(zs, L, L + D, -m, L + m), name="lower ledge"),
              Mesh(rectangle(0.0, -m, L + m, zs, ztop + m), motion=move.to_dict(), name="upper x=0"),
              Mesh(rectangle(L, -m, L + m, zs, ztop + m), motion=move.to_dict(), name="upper x=L"),
              Mesh(ledge(zs, -D, 0.0, -m, L + m), motion=move.to_dict(), name="upper ledge")]
    servo = Servo(servo_gain(deck), stress=sh["normal_stress"], area=L * L, max_speed=sh["max_speed"])
    walls = WallModel(normals=[[0, 0, 1], [0, 0, -1], [0, 1, 0], [0, -1, 0]],
                      points=[[0, 0, 0], [0, 0, ztop], [0, 0, 0], [0, L, 0]], law=law,
                      motions=[None, servo, None, None], meshes=meshes)
    pr = deck["preparation"]
    skin = 0.1 * R if deck["run"]["skin"] == "auto" else float(deck["run"]["skin"])
    system = System(Particles(cloud.positions, cloud.radii, s["density"]),
                    contacts=ContactModel("hertz_mindlin", contact_params(deck, pr["friction"])),
                    walls=walls, integration=Integration(dt=dt, viscous_damping=pr["viscous_damping"]),
                    decomposition=Decomposition(slab_axis=AXES.index(deck["run"]["slab_axis"]), skin=skin))
    try:
        return granular.build_case(comm, system, {"area": L * L, "box": L, "z_split": zs})
    except ValueError as err:
        raise DeckError(str(err)) from None


def servo_gain(deck):
    """The lid servo's gain [m/(N s)]: ``shear.gain_fraction`` of the stability bound
    ``2 / (k dt)`` of one contact of the largest sphere (``Walls.stiffness``, ``Servo.gain_bound``)."""
    s, c = deck["sample"], deck["contacts"]
    law = wall_law("hertz", young=c["young"], poisson=c["poisson"], restitution=c["restitution"], friction=0.0)
    k1 = Walls(np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3)), law).stiffness(s["radius"] * (1.0 + s["dispersity"]))
    return deck["shear"]["gain_fraction"] * 2.0 / (k1 * time_step(deck))


def start_shear(case, deck):
    """Switch the grains' friction on, remove the damping, keep the lid's height at the start."""
    sim = case.sim
    set_contact_params(sim, contact_params(deck, deck["contacts"]["friction"]))
    sim.viscous_damping = 0.0
    case.extras["lid_start"] = lid_height(sim)
    case.extras["shear_step"] = sim.step_count


def lid_height(sim):
    """The lid's height z [m] (its plane is -z = offset)."""
    return -float(sim.plates.offsets[TOP])


def sample(case):
    """One row of ``COLUMNS`` (collective: the kinetic energy)."""
    sim, ex = case.sim, case.extras
    w = sim.plates
    d = float(w.meshes[3].motion.displacement(sim.time - w.time0)[0])
    fs = -float(sum(w.force[k, 0] for k in UPPER))
    fn = float(w.normal_force[TOP])
    area = ex["area"]
    return {"step": sim.step_count, "time": sim.time, "displacement": d, "shear_force": fs,
            "normal_force": fn, "tau": fs / area, "sigma_n": fn / area,
            "friction": fs / fn if fn > 0.0 else math.nan,
            "dilation": lid_height(sim) - ex.get("lid_start", lid_height(sim)),
            "kinetic_energy": sim.kinetic_energy()}


def prepare(case, deck, operations=(), stop=None):
    """Run the preparation to ``preparation.steps`` (StepLimit at ``stop``)."""
    sim = case.sim
    end = deck["preparation"]["steps"]
    n = end - sim.step_count
    if stop is not None and sim.step_count + n > stop:
        sim.run(max(stop - sim.step_count, 0), operations)
        raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), in the preparation")
    sim.run(max(n, 0), operations)


def shear(case, deck, rows, operations=(), stop=None, on_row=None):
    """Shear to ``shear.displacement``, sampling ``output.samples`` rows into ``rows``."""
    sim = case.sim
    start = case.extras["shear_step"]
    total = shear_steps(deck)
    sampler = RowSampler(lambda: sample(case), max(1, total // deck["output"]["samples"]), start + total,
                         rows, on_row)
    if not rows:
        sim.run(0)      # the wall forces of the current state
        sampler(sim)
    n = start + total - sim.step_count
    if stop is not None and sim.step_count + n > stop:
        sim.run(max(stop - sim.step_count, 0), [sampler, *operations])
        raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), in the shear")
    sim.run(max(n, 0), [sampler, *operations])
    return rows


def summary(rows, deck):
    """Peak and residual tau/sigma_n, the dilation at the peak and at the end, the normal stress
    error of the servo (over the rows past 2 % of the displacement: the lid's response)."""
    mu = np.array([r["friction"] for r in rows])
    d = np.array([r["displacement"] for r in rows])
    sig = np.array([r["sigma_n"] for r in rows])
    k = int(np.nanargmax(mu))
    late = d >= 0.75 * d[-1]
    L = deck["sample"]["box"] * deck["sample"]["radius"]
    on = d >= 0.02 * L
    err = np.abs(sig[on] / deck["shear"]["normal_stress"] - 1.0)
    return {"peak_friction": float(mu[k]), "displacement_at_peak": float(d[k]),
            "residual_friction": float(np.nanmean(mu[late])), "dilation_at_peak": float(rows[k]["dilation"]),
            "final_dilation": float(rows[-1]["dilation"]), "final_displacement": float(d[-1]),
            "normal_stress_error_mean": float(err.mean()) if err.size else None,
            "normal_stress_error_max": float(err.max()) if err.size else None}
