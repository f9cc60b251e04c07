"""Point-load response function of a 2D granular packing (driver
``python -m pardem.drivers.response``).

Protocol (any number of ranks; every step is collective):

1. **Packing.** A 2D packing (``[domain] dimension = 2`` of ``pardem.protocols.isotropic``) is
   prepared frictionless in a periodic cell at ``preparation.pressure`` by the isotropic protocol
   (servo and FIRE until its three equilibrium criteria hold; the cell is then fixed).
2. **Replication** (``replicate.copies = [k_x, k_y]``, ``pardem.engine.replicate``): k_x x k_y copies
   of the periodic packing side by side, gids renumbered, contact histories copied: a larger
   system in the same equilibrium without re-equilibrating.
3. **Boundaries.** Periodicity is removed along y (``pardem.engine.open_cell.open_axes``), kept
   along x. Grains whose centres lie within ``boundary.row_thickness`` (default the largest
   diameter, so that no free grain touched a grain across the former y boundary) of the lines
   ``y = y_lo`` and ``y = y_lo + L_y`` form the bottom and the top rows. The bottom row is
   clamped (``Clamp``: x, y and the rotation held: a rigid rough base). The top row, by
   ``boundary.top``:

   * ``"free"`` (default): each of its grains keeps, as a constant load (``DeadLoad``), minus the
     force it has just after the opening (what its contacts across the former boundary gave it),
     and its x and rotation are held (a piston moving along y only), so it is in equilibrium and
     the top is a surface under the confining stress, grain by grain, with ``u_x = 0``: the extra
     load all goes down to the bottom row (Flamant's setting, but for the tangential condition);
   * ``"rigid"``: one body moving vertically (``RigidRow``: x and rotation held, one vertical
     acceleration) under a constant force equal to the packing's push on it in the reference
     state. It also takes none of the extra load at equilibrium, but a load on a grain under it
     mostly unloads that grain's contact with the row, which then presses down on the whole width:
     the response near the top is then nearly uniform (measured: at 2 d below the load the
     profile is flat over 16 d in a 400-grain packing);
   * ``"fixed"``: clamped like the bottom row: the extra load splits between the two rows
     (reported; a load just under it goes mostly into it).
4. **Reference.** Friction ``load.friction`` is switched on (tangential history zero, so the forces
   do not change), contacts undamped, global viscous damping ``relax.damping`` (``"auto"``: twice
   the lowest angular frequency of the layer, ``pi c / (2 H)``, with ``c = sqrt(S / rho_b)`` from
   the contacts' affine stiffness ``S`` and the bulk density ``rho_b``), relaxed until the mean
   unbalanced force is below ``relax.force_tolerance`` of the mean contact force (``"auto"``:
   ``0.01 load.fraction / (2 N)``, so that the residual forces of the N grains move at most 1 % of
   the load, ``residual_share``) and the kinetic
   energy below ``relax.kinetic_tolerance`` (``pardem.protocols.stages.relax``).
5. **Load.** The grain at the top centre (the highest grain not held by a row, the top row's
   grains included with ``"free"``, whose centre lies within one mean diameter of
   ``x = x_lo + L_x / 2``) gets the extra force ``(0, -F, 0)`` with
   ``F = load.fraction`` times the mean contact force (``ExternalForce``).
6. **Dynamic response.** The run goes on undamped; at the times ``dynamic.times`` (in units of the
   transit time ``H / c``) the response is recorded.
7. **Static response.** The damping is switched on again and the packing relaxes to the
   equilibrium criteria of step 4.
8. **More load points** (``load.points = K`` > 1). One packing's response to 1 % of the mean
   contact force follows its force chains; the profile that compares with a continuum is an
   average. The load is taken off (its force set to zero), the packing relaxed again to the
   criteria of step 4 (the next point's reference), and the same force F put on the grain chosen
   as in step 5 at ``x = x_lo + L_x (1/2 + p/K)``; its static response is measured against that
   reference. Points 1 to K-1 have no dynamic stage. The static result is then the average over
   the K points of the profiles binned around each loaded grain (the bins are the same for every
   point: they depend on ``L_x`` and the deck only; the layers below the shallowest common depth
   are kept), with the standard error of each bin, and every point's own measures.

Restart (the driver's ``--restart``, ``--steps``): the stage (preparation, reference, dynamic,
static), the load point, where its relaxation started, the wave speed, the load and the next
dynamic snapshot are a JSON state (``new_state``); the rows, the dead loads of a free top and the
clamps' last reactions (``layer_state``), the gathered reference state, the dynamic responses and
the load points' static responses so far (``response_arrays``) go into the checkpoint's ``/series``; ``restore_layer`` puts the fixes back
in the uninterrupted run's order without re-applying them to the restored forces, so the run
continues bit for bit on the same ranks. The replicated and opened case continues the step count
and clock of the preparation (``engine.granular.continue_clock``).

Measures (``pardem.physics.response``): per grain the change of the Love-Weber moment
``dM_i`` [N m] from the reference state (reference arms, change of the contact forces; its module
docstring derives the force balance), binned in horizontal layers of height
``output.layer_height`` mean diameters and x bins of ``output.x_bin`` mean diameters centred on the
loaded grain: the vertical stress change ``dsigma_yy = sum dM_yy / (dx h t)`` [Pa] (tension
positive: the load gives a negative change) against x at each depth ``z`` below the loaded grain's
centre, with ``t`` the thickness of pardem's 2D stress convention (the mean diameter). Per depth:
the transmitted force ``-t sum dsigma_yy dx`` [N] over F, the profile's second-moment width and half
width at half maximum; against depth: the fits ``w = c z`` (elastic) and ``w = sqrt(2 D z)``
(diffusive). The same measures for Flamant's half-plane ``sigma_yy = -2 F z^3 / (pi t r^4)`` (with
the periodic images of the load, averaged over the same x bins) and for an elastic layer of the
packing's height below the load on a rigid base (``pardem.physics.flamant.layer_sigma_zz``,
Fourier series, 2D Poisson ratio ``comparison.poisson``). The bottom row, a rigid or fixed top row
and the loaded grain are left out of the bins.

Beside the relaxation, each load point's record has ``linear``: the static linear response of the
reference network (``static_linear``: ``pardem.physics.linear_response.StaticResponse``, no
sliding, no opening, under the supports of step 3, ``boundary_conditions``) measured by the same
code (``linear_measure``: the same bins and widths), and ``contact_changes``: the contacts that
opened, closed or slid in the load step, counts [1] (``contact_changes``; the Coulomb limit is
sampled at every relaxation check of the static stage and at the dynamic snapshots, so ``slid``
is a lower bound). With several load points ``static.linear`` is the average of the points'
linear profiles and ``static.contact_changes`` the sums.
"""
import json
import math
import time

import numpy as np

from pardem.config import DeckError, Field, Schema, auto_or, boolean, choice, number, positive
from pardem.engine import fixes as fx
from pardem.engine import granular
from pardem.engine.open_cell import open_axes
from pardem.engine.system import set_contact_params
from pardem.engine.replicate import replicate
from pardem.parallel.exact_sum import exact_sum
from pardem.physics import flamant
from pardem.physics import hertz_mindlin
from pardem.physics import linear_response as lr
from pardem.physics import response as rsp
from pardem.physics.contact_frame import pair_geometry
from pardem.physics.timestep import rayleigh_time_step
from pardem.protocols import deck_checks as dc
from pardem.protocols import isotropic as iso
from pardem.protocols import stages
from pardem.protocols.granular_output import CHECKPOINT_SECTION, REPLICATE_SECTION, StepLimit, run_section
from pardem.protocols import output_deck


def _times_value(name, v):
    if (not isinstance(v, (list, tuple)) or len(v) > 50
            or any(isinstance(k, bool) or not isinstance(k, (int, float)) or not 0.0 < k <= 100.0 for k in v)):
        raise DeckError(f"{name} = {v!r}: expected a list of at most 50 times in (0, 100] (units of the "
                        "transit time H / c); [] for none")
    return sorted(float(k) for k in v)


_times_value.options = None

_PREP = {k: f for k, f in iso.SCHEMA["preparation"].items() if k != "pressures"}
_PREP["pressure"] = Field(1e6, positive(), "pressure p of the frictionless preparation [Pa] "
                                           "(periodic cell, isotropic protocol)")
_PREP["max_steps"] = Field(400000, number(lo=1, lo_open=False, integer=True),
                           "largest number of steps of the preparation")


def run_checks(deck):
    """A normal time step; the step caps within ``MAX_STEPS``; the drag below one velocity per step;
    a row thinner than the packing."""
    s, mat = deck["sample"], deck["material"]
    dt = deck["run"]["dt_fraction"] * rayleigh_time_step(min(s["radii"]), s["density"],
                                                             mat["shear_modulus"], mat["poisson"])
    dc.check_normal(dt, "the time step", "s", "run.dt_fraction, material.shear_modulus, sample.density")
    dc.check_steps(deck["preparation"]["max_steps"] + 3 * deck["relax"]["max_steps"],
                   "preparation.max_steps, relax.max_steps", "the step caps allow a run that")
    dc.check_drag(deck["preparation"]["damping"], dt, "preparation.damping")
    if deck["relax"]["damping"] != "auto":
        dc.check_drag(deck["relax"]["damping"], dt, "relax.damping")
    row = deck["boundary"]["row_thickness"]
    edge = math.sqrt(s["n"] * math.pi * max(s["radii"]) ** 2 / 0.8) * deck["replicate"]["copies"][1]
    if row != "auto" and 4.0 * row >= edge:
        raise DeckError(f"boundary.row_thickness = {row:g} m: expected well below a quarter of the packing's "
                        f"height (about {edge:.3g} m)")


SCHEMA = Schema({
    "sample": iso.SCHEMA["sample"],
    "material": {k: f for k, f in iso.SCHEMA["material"].items() if k != "friction"},
    "preparation": _PREP,
    "equilibrium": iso.SCHEMA["equilibrium"],
    "replicate": REPLICATE_SECTION,
    "boundary": {
        "row_thickness": Field("auto", auto_or(positive()),
                               "grains within this distance [m] of the bottom and top lines form the rigid "
                               "rows; auto = the largest diameter"),
        "top": Field("free", choice("free", "rigid", "fixed"),
                     "top row: free (each grain keeps its reference force as a dead load: a free surface "
                     "under the confining stress; the load goes on its centre grain), rigid (one body moving "
                     "vertically under the constant reference force) or fixed (clamped: the load splits "
                     "between the rows)"),
    },
    "load": {
        "fraction": Field(0.01, number(0.0, 1.0), "extra vertical force F on the top-centre grain, as a "
                                                  "fraction of the mean contact force"),
        "friction": Field(0.3, number(lo=0.0, lo_open=False), "contact friction of the response (0: variant)"),
        "points": Field(1, number(lo=1, hi=64, lo_open=False, hi_open=False, integer=True),
                        "load points K: the force goes in turn on K top grains L_x / K apart, each "
                        "measured against the packing relaxed just before it; the static profiles are "
                        "averaged"),
    },
    "relax": {
        "damping": Field("auto", auto_or(positive()),
                         "global viscous damping C [1/s] of the relaxations; auto = pi c / H (twice the "
                         "lowest angular frequency of the layer)"),
        "force_tolerance": Field("auto", auto_or(dc.tolerance()),
                                 "mean unbalanced force / mean contact force below this (the residual forces "
                                 "may move up to 2 N tol / load.fraction of F; the run notes it when above "
                                 "1 %); auto = 0.01 load.fraction / (2 N): at most 1 % of F"),
        "kinetic_tolerance": Field(1e-14, dc.tolerance(), "E_k / (N p V_mean) below this"),
        "check_every": Field(200, number(lo=1, lo_open=False, integer=True), "steps between checks"),
        "max_steps": Field(300000, number(lo=1, lo_open=False, integer=True),
                           "largest number of steps of each relaxation"),
    },
    "dynamic": {
        "times": Field([0.25, 0.5, 1.0, 2.0], _times_value,
                       "times after the load, in units of the transit time H / c, of the dynamic "
                       "(undamped) response snapshots; [] for none"),
    },
    "comparison": {
        "poisson": Field(0.2, number(-1.0, 1.0), "2D Poisson ratio (K - mu) / (K + mu) of the elastic layer "
                                                 "on a rigid base (Flamant's half-plane needs none)"),
    },
    "run": run_section("Rayleigh critical step",
                       "displacement budget between list rebuilds; auto = 0.2 x the smallest radius"),
    "checkpoint": CHECKPOINT_SECTION,
    "output": output_deck.output_section(
        before={"layer_height": Field(1.0, number(0.1, 100.0), "height of the horizontal layers [mean diameters]"),
                "x_bin": Field(1.0, number(0.1, 100.0), "width of the x bins [mean diameters]")},
        vtk=output_deck.vtk_every("DIR/paraview", of="the whole state"),
        after={"perturbation_vtk": Field(True, boolean, "ParaView snapshots of the perturbation (DIR/response_vtk: "
                                                        "dsigma_yy, displacement per grain) at each record")},
        plot_figures="response.png"),
}, checks=(iso.sample_checks, run_checks, iso.pressure_checks))

SERIES_COLUMNS = ("step", "time", "stage", "unbalanced", "kinetic", "top_force", "bottom_force")
SERIES_UNITS = ("1", "s", "1", "1", "1", "N", "N")
SERIES_INT = ("step", "stage")
# the run's stages (``pardem.protocols.stages.run_stages``): the preparation (resumable: ``stages.prepare``;
# the layer is replicated and opened at its end, no step) and the response (``respond``, which resumes
# its own sub-stages ``STAGES`` from its state)
RUN_STAGES = ("prepare", "respond")
STAGES = ("reference", "dynamic", "static")
SERIES_DESCRIPTION = ("pardem response series: one row per check of the relaxations: stage (0 reference, "
                      "1 dynamic, 2 static), mean unbalanced force over the mean contact force, kinetic = "
                      "E_k / (N p V_mean), the vertical force of the packing on the top and bottom rows "
                      "[N] (positive up)")


def iso_deck(deck):
    """The isotropic protocol's deck of this deck's preparation (2D, one pressure, no moduli)."""
    prep = {k: v for k, v in deck["preparation"].items() if k != "pressure"}
    prep["pressures"] = [deck["preparation"]["pressure"]]
    mat = dict(deck["material"], friction=0.0)
    return {"domain": {"dimension": 2}, "sample": deck["sample"], "material": mat, "preparation": prep,
            "equilibrium": deck["equilibrium"], "moduli": {"enabled": False, "strain": "auto",
                                                           "max_relax_steps": 1}, "run": deck["run"]}


# ---------------------------------------------------------------------------------------------
# the rigid top row

class RigidRow:
    """A row of grains (``gids``) moving as one rigid body along y under a constant extra force.

    Each step (stage CONSTRAINT, after the loads): x and the rotation of its grains are held
    (force, torque and velocity zeroed), and their vertical forces are replaced by ``m_i (F_y +
    applied) / M``: the total vertical force on the row (contacts and drag, an exact sum over the
    ranks) plus ``applied`` [N], shared in proportion to the masses, so all its grains keep one
    vertical velocity. ``applied``: None takes minus the row's force at the first call (the row
    is then in equilibrium in that state). ``self.force`` [N]: the total vertical force of the
    packing on the row at the last call (same on every rank).
    """
    stage = fx.CONSTRAINT

    def __init__(self, gids, applied=None):
        self.selection = fx.ElementSelection(gids, "top row gids")
        self.applied = None if applied is None else float(applied)
        self.force = 0.0
        self._mass = None

    def post_force(self, sim):
        e = sim.elements
        rows, _ = self.selection.rows(e, sim.comm)
        cols = np.zeros((max(len(rows), 1), 2))
        cols[:len(rows), 0] = e.f[rows, 1]
        cols[:len(rows), 1] = e.mass[rows]
        total = exact_sum(sim.comm, cols)
        self.force = float(total[0])
        if self.applied is None:
            self.applied = -self.force
        if len(rows):
            acc = (self.force + self.applied) / float(total[1])
            e.f[rows, 0] = 0.0
            e.v[rows, 0] = 0.0
            e.f[rows, 1] = e.mass[rows] * acc
            e.t[rows] = 0.0
            e.w[rows] = 0.0


class DeadLoad:
    """Constant loads on the grains ``gids`` equal to minus their force at the first call: each
    grain is then in equilibrium in that state and keeps the same force and torque whatever
    happens (a free surface under the confining stress, grain by grain). Stage LOAD. The loads are
    gathered over the ranks at the first call (every rank holds them all, by gid), so they follow
    grains that migrate. ``self.force`` [k, 3] [N], ``self.torque`` [k, 3] [N m] after it."""
    stage = fx.LOAD

    def __init__(self, gids):
        self.selection = fx.ElementSelection(gids, "top row gids")
        self.force = None
        self.torque = None

    def post_force(self, sim):
        e = sim.elements
        rows, idx = self.selection.rows(e, sim.comm)
        if self.force is None:
            parts = sim.comm.allgather((idx, -e.f[rows], -e.t[rows]))
            k = len(self.selection.gids)
            self.force, self.torque = np.zeros((k, 3)), np.zeros((k, 3))
            for i, f, t in parts:
                self.force[i] = f
                self.torque[i] = t
        e.f[rows] += self.force[idx]
        e.t[rows] += self.torque[idx]


# ---------------------------------------------------------------------------------------------
# contacts and grains gathered

def contact_table(sim):
    """This rank's touching contacts counted once: ``gid_i, gid_j`` [n_c], unit ``normal`` [n_c, 3]
    from i to j, contact ``arm_i, arm_j`` [n_c] [m], ``force`` on i [n_c, 3] [N] (elastic normal
    plus tangential history: the static force; undamped contacts)."""
    e, c = sim.elements, sim.contacts
    d, n, dist, delta = pair_geometry(c.i, c.j, c.shift, e.x, e.radius)
    keep = (delta > 0.0) & c.counted_once(e.n_owned)
    ri, rj = e.radius[c.i[keep]], e.radius[c.j[keep]]
    n, dist, delta = n[keep], dist[keep], delta[keep]
    fn = c.law.elastic_normal_force(c.params, ri, rj, delta)
    force = c.history[keep, :3] - fn[:, None] * n
    a_i, a_j = rsp.contact_arms(dist, ri, rj)
    return {"gid_i": e.gid[c.i[keep]].astype(np.int64), "gid_j": e.gid[c.j[keep]].astype(np.int64),
            "normal": n, "arm_i": a_i, "arm_j": a_j, "force": force}


def gather_state(sim):
    """Rank 0: the contacts (``contact_table``, each pair once, ordered by gid pair) and the grains
    by gid (``x`` [n, 3], ``radius`` [n]); None elsewhere. Collective."""
    e = sim.elements
    parts = sim.comm.gather({"c": contact_table(sim), "gid": e.gid[:e.n_owned], "x": e.x[:e.n_owned],
                             "r": e.radius[:e.n_owned]})
    if not sim.comm.is_root:
        return None
    c = {k: np.concatenate([p["c"][k] for p in parts]) for k in parts[0]["c"]}
    o = np.lexsort((c["gid_j"], c["gid_i"]))
    c = {k: v[o] for k, v in c.items()}
    gid = np.concatenate([p["gid"] for p in parts])
    x = np.zeros((len(gid), 3))
    r = np.zeros(len(gid))
    x[gid] = np.concatenate([p["x"] for p in parts])
    r[gid] = np.concatenate([p["r"] for p in parts])
    return {"contacts": c, "x": x, "radius": r}


# ---------------------------------------------------------------------------------------------
# building the loaded layer

def prepared(comm, deck, progress=None):
    """The frictionless packing at ``preparation.pressure`` in its periodic cell (step 1), and the
    preparation's info (``stages.prepare``)."""
    d = iso_deck(deck)
    case, info = stages.prepare(comm, d, deck["preparation"]["pressure"], progress=progress)
    case.sim.elements.v[:] = 0.0
    case.sim.elements.w[:] = 0.0
    return case, info


class Layer:
    """The loaded layer: the open case and its rows, load and constants (see ``make_layer``)."""

    def __init__(self, case, bottom, top, free, top_fix, bottom_fix, geometry):
        self.case = case
        self.bottom, self.top, self.free = bottom, top, free
        self.top_fix, self.bottom_fix = top_fix, bottom_fix
        self.geometry = geometry
        self.load = None
        self.loaded_gid = None
        # the grains that move under the contacts and loads alone: binned, and candidates for the load
        self.binned = np.sort(np.concatenate([free, top])) if isinstance(top_fix, DeadLoad) else free
        self.force = 0.0
        self.damping = 0.0
        self.ref = None          # rank 0: the reference state (``gather_state``), once measured
        self.records = None      # rank 0: the dynamic responses measured so far (list of dicts)
        self.points = None       # rank 0: the static responses of the load points done (list of dicts)
        self.last_per_grain = None   # rank 0: the last static response per grain (``measure``'s)
        self.limit_keys = None   # rank 0: pair keys of the contacts seen at the Coulomb limit in the load step

    @property
    def sim(self):
        return self.case.sim

    def reactions(self):
        """``(top, bottom)``: the vertical force [N] of the packing on the top and bottom rows
        (positive up; collective)."""
        sim = self.sim
        if isinstance(self.top_fix, RigidRow):
            top = self.top_fix.force
        elif isinstance(self.top_fix, DeadLoad):
            # the row's loads are constant: the packing's force on it is minus them (at equilibrium)
            top = 0.0 if self.top_fix.force is None else -float(np.sum(self.top_fix.force[:, 1]))
        else:
            top = -float(exact_sum(sim.comm, np.array([self.top_fix.reaction[1]])))
        bottom = -float(exact_sum(sim.comm, np.array([self.bottom_fix.reaction[1]])))
        return top, bottom


def make_layer(comm, case, deck, progress=None):
    """Steps 2 and 3: replicate, open y, make the rows, friction on. Returns a ``Layer``; its case
    continues the step count and clock of ``case`` (the steps, series and checkpoints of a run
    count from its start)."""
    step, clock = case.sim.step_count, case.sim.time
    k = deck["replicate"]["copies"]
    if k != [1, 1]:
        case = replicate(comm, case, k)
        if progress is not None:
            progress.say(f"replicated {k[0]} x {k[1]}: {case.n_elements} grains")
    cell = case.sim.cell
    lo, L = cell.lo.copy(), cell.length.copy()
    new = open_axes(comm, case, ("y",))
    sim = new.sim
    e = sim.elements
    parts = comm.allgather((e.gid[:e.n_owned], e.x[:e.n_owned, 1], e.radius[:e.n_owned]))
    gid = np.concatenate([p[0] for p in parts])
    y = np.zeros(len(gid))
    r = np.zeros(len(gid))
    y[gid] = np.concatenate([p[1] for p in parts])
    r[gid] = np.concatenate([p[2] for p in parts])
    row = deck["boundary"]["row_thickness"]
    row = 2.0 * float(r.max()) if row == "auto" else float(row)
    bottom = np.nonzero(y < lo[1] + row)[0]
    top = np.nonzero(y >= lo[1] + L[1] - row)[0]
    free = np.nonzero((y >= lo[1] + row) & (y < lo[1] + L[1] - row))[0]
    if len(bottom) == 0 or len(top) == 0 or len(free) == 0:
        raise ValueError("boundary.row_thickness leaves a row or the free grains empty")
    mat = deck["material"]
    set_contact_params(new.sim, stages.contact_params(mat, deck["load"]["friction"], 1.0))
    # the forces of the opened state at the run's step; the fixes added below act on them at once
    granular.continue_clock(sim, step, clock)
    geometry = {"lo": lo.tolist(), "length": L.tolist(), "row_thickness": row,
                "n_grains": int(len(gid)), "n_bottom": int(len(bottom)), "n_top": int(len(top)),
                "n_free": int(len(free)), "mean_diameter": float(2.0 * r.mean()),
                "thickness": float(cell.thickness), "y": y, "radius": r}
    bottom_fix, top_fix, extra = _row_fixes(deck, bottom, top)
    fx.add(sim, bottom_fix, top_fix, *extra)
    return Layer(new, bottom, top, free, top_fix, bottom_fix, geometry)


def _row_fixes(deck, bottom, top):
    """``(bottom clamp, top fix, [extra fixes])`` of the rows (module docstring, step 3)."""
    bottom_fix = fx.Clamp(bottom, dofs="xyz", rotations="xyz")
    kind = deck["boundary"]["top"]
    top_fix = (DeadLoad(top) if kind == "free" else RigidRow(top) if kind == "rigid"
               else fx.Clamp(top, dofs="xyz", rotations="xyz"))
    # pistons: x and the rotation held, y free under the dead load (without this the surface
    # grains, which have no stiffness against rolling off, flowed by a diameter)
    extra = [fx.Clamp(top, dofs="x", rotations="xyz")] if kind == "free" else []
    return bottom_fix, top_fix, extra


def _insert(sim, *fixes):
    """``fixes.add`` without applying the fixes to the current forces: a restored state's forces
    already hold them (the checkpoint stores the forces after the fixes)."""
    for fix in fixes:
        stage = getattr(fix, "stage", fx.LOAD)
        at = len(sim.fixes)
        while at > 0 and getattr(sim.fixes[at - 1], "stage", fx.LOAD) > stage:
            at -= 1
        sim.fixes.insert(at, fix)


# ---------------------------------------------------------------------------------------------
# restart: the layer's and the response's state in a checkpoint

def layer_state(layer):
    """``(state, arrays)`` of the layer for a checkpoint: ``state`` JSON-able (geometry scalars,
    top row kind and its load, the clamps' reactions of every rank, the load), ``arrays`` {name:
    1D array} (row gids, the dead loads; HDF5 attributes are too small for them). Collective: the
    clamps' reactions (each rank's sum over its clamped grains) are gathered."""
    comm = layer.sim.comm
    clamps = [f for f in (layer.bottom_fix, layer.top_fix) if isinstance(f, fx.Clamp)]
    mine = [[f.reaction.tolist(), f.reaction_torque.tolist()] for f in clamps]
    st = {"geometry": {k: v for k, v in layer.geometry.items() if k not in ("y", "radius")},
          "reactions": comm.allgather(mine), "loaded_gid": layer.loaded_gid, "force": layer.force,
          "rigid": None}
    arrays = {"layer_bottom": np.asarray(layer.bottom, np.int64), "layer_top": np.asarray(layer.top, np.int64)}
    t = layer.top_fix
    if isinstance(t, DeadLoad):
        arrays["layer_dead_force"] = np.asarray(t.force, np.float64).ravel()
        arrays["layer_dead_torque"] = np.asarray(t.torque, np.float64).ravel()
    elif isinstance(t, RigidRow):
        st["rigid"] = {"applied": t.applied, "force": t.force}
    return st, arrays


def restore_layer(case, deck, st, series):
    """The ``Layer`` of a checkpoint (``layer_state`` outputs; ``series`` the checkpoint's
    ``/series``) on the restored ``case``: its rows' fixes and the load put back in the order of
    the uninterrupted run, with their state, so that the run continues bit for bit."""
    sim = case.sim
    bottom = np.asarray(series["layer_bottom"], np.int64)
    top = np.asarray(series["layer_top"], np.int64)
    g = dict(st["geometry"])
    free = np.setdiff1d(np.arange(g["n_grains"], dtype=np.int64), np.concatenate([bottom, top]))
    bottom_fix, top_fix, extra = _row_fixes(deck, bottom, top)
    if isinstance(top_fix, DeadLoad):
        top_fix.force = np.asarray(series["layer_dead_force"], np.float64).reshape(-1, 3).copy()
        top_fix.torque = np.asarray(series["layer_dead_torque"], np.float64).reshape(-1, 3).copy()
    elif isinstance(top_fix, RigidRow):
        top_fix.applied, top_fix.force = float(st["rigid"]["applied"]), float(st["rigid"]["force"])
    clamps = [f for f in (bottom_fix, top_fix) if isinstance(f, fx.Clamp)]
    per_rank = st["reactions"]
    if len(per_rank) == sim.comm.size:
        mine = per_rank[sim.comm.rank]
    else:   # another rank count: rank 0 holds the sums (only their global sum is read)
        mine = [[np.sum([p[k][0] for p in per_rank], axis=0), np.sum([p[k][1] for p in per_rank], axis=0)]
                if sim.comm.is_root else [np.zeros(3), np.zeros(3)] for k in range(len(clamps))]
    for f, (force, torque) in zip(clamps, mine):
        f.reaction[:] = force
        f.reaction_torque[:] = torque
    _insert(sim, bottom_fix, top_fix, *extra)
    layer = Layer(case, bottom, top, free, top_fix, bottom_fix, g)
    if st["loaded_gid"] is not None:
        layer.loaded_gid = int(st["loaded_gid"])
        layer.load = fx.ExternalForce([layer.loaded_gid], (0.0, -float(st["force"]), 0.0))
        layer.force = float(st["force"])
        _insert(sim, layer.load)
    return layer


_REF_CONTACTS = (("gid_i", np.int64, 1), ("gid_j", np.int64, 1), ("normal", np.float64, 3),
                 ("arm_i", np.float64, 1), ("arm_j", np.float64, 1), ("force", np.float64, 3))


def response_arrays(layer):
    """Rank 0's {name: 1D array} of the reference state (``gather_state``) and the dynamic records
    so far (JSON text as bytes), for a checkpoint; {} elsewhere or before the reference."""
    out = {}
    if layer.ref is not None:
        for k, _, _ in _REF_CONTACTS:
            out[f"ref_{k}"] = np.asarray(layer.ref["contacts"][k]).ravel()
        out["ref_x"] = layer.ref["x"].ravel()
        out["ref_radius"] = layer.ref["radius"]
    if layer.records is not None:
        out["records_json"] = np.frombuffer(json.dumps(layer.records).encode(), dtype=np.uint8)
    if layer.points:
        out["points_json"] = np.frombuffer(json.dumps(layer.points).encode(), dtype=np.uint8)
    if layer.limit_keys is not None and len(layer.limit_keys):
        out["limit_keys"] = np.asarray(layer.limit_keys, np.int64)
    return out


def restore_response(layer, series):
    """Put back rank 0's reference state, dynamic records and load points (``response_arrays``)
    into ``layer``."""
    if not layer.sim.comm.is_root:
        return
    if "ref_x" in series:
        c = {k: np.asarray(series[f"ref_{k}"], dtype=t).reshape((-1, w) if w > 1 else (-1,))
             for k, t, w in _REF_CONTACTS}
        layer.ref = {"contacts": c, "x": np.asarray(series["ref_x"], np.float64).reshape(-1, 3),
                     "radius": np.asarray(series["ref_radius"], np.float64)}
    if "records_json" in series:
        layer.records = json.loads(bytes(np.asarray(series["records_json"], np.uint8)).decode())
    if "points_json" in series:
        layer.points = json.loads(bytes(np.asarray(series["points_json"], np.uint8)).decode())
    if "limit_keys" in series:
        layer.limit_keys = np.asarray(series["limit_keys"], np.int64)


def wave_speed(layer):
    """``(c [m/s], H [m])``: the affine wave speed ``sqrt(S / rho_b)`` (``S = kd2 / (2 V) + p``, the
    frictionless affine stiffness of the contacts, ``rho_b`` the mass over ``L_x L_y t``) and the
    height between the rows' inner lines. Collective."""
    sim = layer.sim
    kd2 = sim.contacts.global_affine_stiffness(sim.comm, sim.elements)
    V = sim.cell.volume
    p = max(sim.cell.pressure(sim.global_stress()), 0.0)
    S = kd2 / (2.0 * V) + p
    mass = float(exact_sum(sim.comm, sim.elements.mass[:sim.elements.n_owned]))
    g = layer.geometry
    H = g["length"][1] - 2.0 * g["row_thickness"]
    return math.sqrt(S / (mass / V)), H


class _Run:
    """What ``stages.relax`` needs of a run: operations, a check callback, the stop step."""

    def __init__(self, operations=(), on_check=None, stop=None):
        self.operations = list(operations)
        self.on_check = on_check
        self.stop = stop

    def before_run(self, sim):
        if self.stop is not None and sim.step_count >= self.stop:
            raise StepLimit(f"stopped at step {sim.step_count} (--steps {self.stop})")


def relax_layer(layer, deck, label, progress=None, operations=(), on_check=None, start=None, stop=None):
    """Relax with the damping of ``layer.damping`` until the ``[relax]`` criteria hold, counting
    from step ``start`` (default now: a restarted relaxation continues from its start); returns
    ``(balance, converged, steps)``. ``stop``: raise ``StepLimit`` at the first check at or after
    this step."""
    r = deck["relax"]
    sim = layer.sim
    sim.viscous_damping = layer.damping
    tol = {"kinetic_tolerance": r["kinetic_tolerance"],
           "force_tolerance": relax_tolerance(deck, layer.geometry["n_grains"]),
           "pressure_tolerance": 1.0}
    return stages.relax(sim, tol, r["check_every"], r["max_steps"], progress=progress, label=label,
                     start=start, run=_Run(operations, on_check, stop))


AUTO_SHARE = 0.01       # relax.force_tolerance = "auto": the residual forces move at most this share of F


def relax_tolerance(deck, n):
    """``relax.force_tolerance`` for a layer of ``n`` grains, "auto" resolved to the tolerance whose
    ``residual_share`` is ``AUTO_SHARE``."""
    tol = deck["relax"]["force_tolerance"]
    return AUTO_SHARE * deck["load"]["fraction"] / (2.0 * n) if tol == "auto" else float(tol)


def residual_share(n, force_tolerance, fraction):
    """The bound on the rows' share of F that the relaxations' residual forces can move:
    ``N (u_ref + u_static) <f_c> / F = 2 N tol / fraction`` (``unbalanced`` = mean |R| over the
    mean contact force, at most ``force_tolerance`` in each relaxation; F = ``fraction`` <f_c>)."""
    return 2.0 * n * force_tolerance / fraction


def tolerance_note(n, force_tolerance, fraction, share=AUTO_SHARE):
    """A one-line note when ``relax.force_tolerance`` lets the residual forces of ``n`` grains
    move more than ``share`` of F (``residual_share``), else None."""
    bound = residual_share(n, force_tolerance, fraction)
    if bound <= share:
        return None
    return (f"note: relax.force_tolerance = {force_tolerance:g} lets the residual forces of {n} grains move up to "
            f"{bound:.3g} F (2 N tol / load.fraction); at most {share * fraction / (2.0 * n):.2g} keeps it "
            f"within {share:g} F")


def loaded_grain(layer, shift=0.0):
    """The gid of the highest grain not held by a row (with ``boundary.top = "free"`` the top row's
    grains count) whose centre lies within one mean diameter of the line
    ``x = x_lo + L_x (1/2 + shift)`` (periodic; collective)."""
    sim = layer.sim
    e = sim.elements
    parts = sim.comm.allgather((e.gid[:e.n_owned], e.x[:e.n_owned, :2]))
    gid = np.concatenate([p[0] for p in parts])
    x = np.concatenate([p[1] for p in parts])
    g = layer.geometry
    xc = g["lo"][0] + (0.5 + shift) * g["length"][0]
    free = np.isin(gid, layer.binned)
    dx = rsp.relative_x(x[:, 0], xc, g["length"][0])
    cand = free & (np.abs(dx) < g["mean_diameter"])
    if not cand.any():
        raise ValueError(f"no free grain within one mean diameter of x = {xc:.6g} m at the top")
    k = np.nonzero(cand)[0][np.argmax(x[cand, 1])]
    return int(gid[k])


def apply_load(layer, force, gid=None):
    """Put (or change) the extra force ``(0, -force, 0)`` [N] on grain ``gid`` (default: the
    loaded grain, or the top-centre one, ``loaded_grain``, if none is yet). A load moved to another
    grain replaces the old one's fix (which must carry no force then) at its place in the fixes."""
    if gid is None:
        gid = layer.loaded_gid if layer.load is not None else loaded_grain(layer)
    if layer.load is not None and gid != layer.loaded_gid:
        if np.any(layer.load.force != 0.0):
            raise ValueError("apply_load: take the load off (force 0) before moving it to another grain")
        layer.sim.fixes.remove(layer.load)
        layer.load = None
    if layer.load is None:
        layer.loaded_gid = int(gid)
        layer.load = fx.ExternalForce([layer.loaded_gid], (0.0, -float(force), 0.0))
        fx.add(layer.sim, layer.load)      # its force acts on the current forces at once
    else:
        layer.load.force[:] = (0.0, -float(force), 0.0)
    layer.force = float(force)


# ---------------------------------------------------------------------------------------------
# measures

def bins(layer, ref, loaded_xy, deck):
    """``(x_edges [nx + 1], z_edges [nz + 1])`` [m] relative to the loaded grain: x bins of
    ``output.x_bin`` mean diameters (an odd number, the middle one centred on the load, covering the
    period), layers of ``output.layer_height`` from half a layer below the load to the top of the
    bottom row."""
    g = layer.geometry
    d = g["mean_diameter"]
    Lx = g["length"][0]
    w = deck["output"]["x_bin"] * d
    nx = max(1, int(Lx // w))
    nx -= (nx + 1) % 2       # odd: one bin centred on the load
    nx = max(nx, 1)
    w = Lx / nx
    x_edges = (np.arange(nx + 1) - nx / 2.0) * w
    h = deck["output"]["layer_height"] * d
    bottom_line = g["lo"][1] + g["row_thickness"]
    depth = loaded_xy[1] - bottom_line
    nz = int((depth - 0.5 * h) // h)
    if nz < 1:
        raise ValueError("output.layer_height: no layer fits between the load and the bottom row")
    z_edges = 0.5 * h + np.arange(nz + 1) * h
    return x_edges, z_edges


def measure(layer, ref, cur, deck):
    """Rank 0: the binned response of the state ``cur`` against ``ref`` (``gather_state``
    outputs), dict of lists (see the module docstring); None elsewhere."""
    if ref is None:
        return None
    g = layer.geometry
    n = g["n_grains"]
    dM = rsp.moment_change(n, ref["contacts"], cur["contacts"])
    x0 = ref["x"][layer.loaded_gid]
    x_edges, z_edges = bins(layer, ref, x0, deck)
    Lx, t = g["length"][0], g["thickness"]
    free = np.zeros(n, bool)
    free[layer.binned] = True
    free[layer.loaded_gid] = False
    xr = rsp.relative_x(ref["x"][:, 0], x0[0], Lx)[free]
    z = (x0[1] - ref["x"][:, 1])[free]
    dyy = dM[free, 1, 1]
    sigma, counts = rsp.bin_stress(xr, z, dyy, x_edges, z_edges, t)
    H = x0[1] - (g["lo"][1] + g["row_thickness"])
    disp = cur["x"] - ref["x"]
    out = profile_measures(sigma, counts, x_edges, z_edges, layer.force, t, Lx, H, deck["comparison"]["poisson"])
    out.update(loaded_gid=int(layer.loaded_gid), loaded_position=x0.tolist(),
               max_displacement=float(np.max(np.abs(disp[:, :2]))),
               per_grain={"dM_yy": dM[:, 1, 1], "displacement": disp})
    return out


def profile_measures(sigma, counts, x_edges, z_edges, F, t, Lx, H, poisson):
    """The measures of a binned response ``sigma`` [nz, nx] [Pa] (``counts`` grains per bin) of a
    load ``F`` [N]: transmitted force per layer over F, widths, their fits, and the same for
    Flamant (periodic images, period ``Lx`` [m]) and for the layer of height ``H`` [m] on a rigid
    base (2D Poisson ratio ``poisson``); dict of lists (the module docstring)."""
    sigma = np.asarray(sigma, np.float64)
    xc = 0.5 * (x_edges[1:] + x_edges[:-1])
    zc = 0.5 * (z_edges[1:] + z_edges[:-1])
    dx = np.diff(x_edges)
    transmitted = -t * (sigma * dx[None, :]).sum(axis=1) / F        # per layer, / F
    widths = [rsp.widths(xc, -row) for row in sigma]
    fl = flamant.flamant_bin_average(x_edges, zc, F, t, period=Lx, images=200)
    lay = flamant.layer_sigma_zz(xc, zc, F, t, H, Lx, poisson, bin_width=float(dx[0]))
    fw = [rsp.widths(xc, -row) for row in fl]
    lw = [rsp.widths(xc, -row) for row in lay]

    def col(ws, k):
        return [None if w[k] is None else float(w[k]) for w in ws]

    return {"x": xc.tolist(), "depth": zc.tolist(), "x_edges": np.asarray(x_edges).tolist(),
            "z_edges": np.asarray(z_edges).tolist(),
            "dsigma_yy": sigma.tolist(), "grains_per_bin": np.asarray(counts).tolist(),
            "transmitted_over_F": transmitted.tolist(),
            "width_second_moment": col(widths, 0), "width_half_max": col(widths, 1),
            "flamant": {"dsigma_yy": fl.tolist(), "width_second_moment": col(fw, 0),
                        "width_half_max": col(fw, 1)},
            "layer_on_rigid_base": {"dsigma_yy": lay.tolist(), "width_second_moment": col(lw, 0),
                                    "width_half_max": col(lw, 1), "height": float(H), "poisson": poisson},
            "fits_half_max": rsp.fit_widths(zc, [np.nan if w[1] is None else w[1] for w in widths]),
            "fits_second_moment": rsp.fit_widths(zc, [np.nan if w[0] is None else w[0] for w in widths])}


POINT_KEYS = ("loaded_gid", "loaded_position", "dsigma_yy", "grains_per_bin", "transmitted_over_F",
              "width_second_moment", "width_half_max", "max_displacement", "reference", "static", "bottom_share",
              "top_share", "contact_changes", "linear")
POINT_BINS = ("x_edges", "z_edges", "force")


def average_points(points, geometry, poisson):
    """The static response averaged over load points (``points``: each a dict of ``POINT_KEYS``
    with ``x_edges``, ``z_edges`` and ``force``, the same F and x bins for all): the mean profile
    over the layers every point has, its measures (``profile_measures``; the layer on a rigid base
    at the mean height below the loads), ``dsigma_yy_sem`` (standard error of each bin's mean over
    the points, [Pa]) and ``points`` (K)."""
    nz = min(len(p["dsigma_yy"]) for p in points)
    x_edges = np.asarray(points[0]["x_edges"])
    for p in points:
        if not np.array_equal(np.asarray(p["x_edges"]), x_edges) or p["force"] != points[0]["force"]:
            raise ValueError("load points with different x bins or forces cannot be averaged")
    stack = np.array([np.asarray(p["dsigma_yy"])[:nz] for p in points])
    counts = np.sum([np.asarray(p["grains_per_bin"])[:nz] for p in points], axis=0)
    K = len(points)
    sem = stack.std(axis=0, ddof=1) / math.sqrt(K) if K > 1 else np.zeros_like(stack[0])
    bottom_line = geometry["lo"][1] + geometry["row_thickness"]
    H = float(np.mean([p["loaded_position"][1] - bottom_line for p in points]))
    out = profile_measures(stack.mean(axis=0), counts, x_edges, np.asarray(points[0]["z_edges"])[:nz + 1],
                           points[0]["force"], geometry["thickness"], geometry["length"][0], H, poisson)
    out.update(dsigma_yy_sem=sem.tolist(), points=K)
    return out


# ---------------------------------------------------------------------------------------------
# the static linear response of the reference network (``pardem.physics.linear_response``)

def boundary_conditions(layer):
    """``(held [n, 6], ties)`` of ``linear_response.StaticResponse``: the supports of the
    relaxations (step 3): every grain in the plane (u_z, theta_x, theta_y held); the bottom row
    clamped; the top row clamped (``"fixed"``), or x and the rotations held with y free under its
    constant dead load (``"free"``: a dead load adds no stiffness) or y tied into one rigid row
    under its constant force (``"rigid"``)."""
    n = layer.geometry["n_grains"]
    held = np.zeros((n, 6), dtype=bool)
    held[:, list(lr.PLANE_HELD)] = True
    held[layer.bottom] = True
    ties = []
    if isinstance(layer.top_fix, fx.Clamp):
        held[layer.top] = True
    else:
        held[layer.top, 0] = True
        held[layer.top, 3:] = True
        if isinstance(layer.top_fix, RigidRow):
            ties.append((np.asarray(layer.top, np.int64), 1))
    return held, ties


def reference_network(layer, ref, deck):
    """The Hertz-Mindlin ``Network`` (rows = gids) of the gathered reference state ``ref``."""
    g = layer.geometry
    mat = deck["material"]
    e_star, g_star = hertz_mindlin.effective_moduli(stages.young_modulus(mat), mat["poisson"])
    c = ref["contacts"]
    volume = g["length"][0] * g["length"][1] * g["thickness"]
    return lr.contact_network(g["n_grains"], c["gid_i"], c["gid_j"], c["normal"], c["arm_i"], c["arm_j"],
                              ref["radius"], volume, e_star, g_star)


def static_linear(layer, ref, deck, force=None, torque=None, solver=None):
    """Rank 0: the static linear response of the reference state ``ref`` (``gather_state``) under
    the relaxations' supports (``boundary_conditions``) to the loads ``force`` [n, 3] [N] and
    ``torque`` [n, 3] [N m] by gid (default: the layer's load ``(0, -F, 0)`` on its loaded grain):
    ``StaticResponse.solve``'s dict (``u``, ``theta``, contact ``force`` changes in the order of
    ``ref["contacts"]``, reactions, residual), and ``solver`` (the factorised ``StaticResponse``,
    reusable by passing it back)."""
    n = layer.geometry["n_grains"]
    if force is None:
        force = np.zeros((n, 3))
        force[layer.loaded_gid, 1] = -layer.force
    if solver is None:
        held, ties = boundary_conditions(layer)
        solver = lr.StaticResponse(reference_network(layer, ref, deck), held, ties)
    out = solver.solve(force, torque)
    c = ref["contacts"]
    if solver.net.n_contacts != len(c["gid_i"]):
        # a contact whose overlap rounds to zero from its arms is left out of the network (no force,
        # no stiffness): the changes go back to the table's rows (sorted by gid pair, as the keys)
        idx = np.searchsorted(lr.pair_keys(c["gid_i"], c["gid_j"]), lr.pair_keys(solver.net.i, solver.net.j))
        for k in ("force", "torque_i", "torque_j"):
            full = np.zeros((len(c["gid_i"]), 3))
            full[idx] = out[k]
            out[k] = full
    out["solver"] = solver
    return out


def linear_state(ref, linear):
    """The state (``gather_state``'s form) of the reference ``ref`` moved by the static linear
    response ``linear``: contact forces plus their changes, centres plus ``u``; the reference's
    normals and arms (``measure`` reads the reference's)."""
    c = dict(ref["contacts"])
    c["force"] = np.asarray(c["force"]) + linear["force"]
    return {"contacts": c, "x": ref["x"] + linear["u"], "radius": ref["radius"]}


def linear_measure(layer, ref, deck, linear=None):
    """Rank 0: the static linear response measured as the relaxed one (``measure`` of
    ``linear_state``: the same bins, profile and widths), with the solve's ``residual``, the
    backbone's grains and contacts, and ``force`` [N]."""
    linear = static_linear(layer, ref, deck) if linear is None else linear
    out = measure(layer, ref, linear_state(ref, linear), deck)
    out.pop("per_grain", None)
    sv = linear["solver"]
    out.update(residual=linear["residual"], backbone_grains=int(sv.kept.sum()),
               backbone_contacts=int(sv.contacts.sum()), force=layer.force)
    return out


def sample_limit(layer, friction):
    """Collect (rank 0, ``layer.limit_keys``) the pair keys of the contacts at the Coulomb limit
    now (``linear_response.at_coulomb_limit``). Collective."""
    sim = layer.sim
    c = contact_table(sim)
    lim = lr.at_coulomb_limit(c["normal"], c["force"], friction)
    gi, gj = c["gid_i"][lim], c["gid_j"][lim]
    keys = lr.pair_keys(np.minimum(gi, gj), np.maximum(gi, gj))
    parts = sim.comm.gather(keys)
    if sim.comm.is_root:
        layer.limit_keys = np.union1d(np.zeros(0, np.int64) if layer.limit_keys is None else layer.limit_keys,
                                      np.concatenate(parts))


def contact_changes(layer, ref, cur, deck):
    """Rank 0: the contacts that changed state in the load step, counts [1]: ``opened`` (touching
    in the reference, not in the loaded state), ``closed`` (the reverse), ``slid`` (at the Coulomb
    limit in the loaded state or at a sampled time of the load step, the relaxation checks every
    ``relax.check_every`` steps and the dynamic snapshots, and not in the reference: a lower bound,
    a contact may slide and unload between samples), ``at_coulomb_limit_reference``,
    ``at_coulomb_limit_loaded``."""
    friction = deck["load"]["friction"]
    ch = lr.state_changes(ref["contacts"], cur["contacts"], friction)
    c0 = ref["contacts"]
    k0 = lr.pair_keys(c0["gid_i"], c0["gid_j"])[lr.at_coulomb_limit(c0["normal"], c0["force"], friction)]
    seen = np.union1d(ch["new_at_limit_keys"], np.zeros(0, np.int64) if layer.limit_keys is None
                      else np.setdiff1d(layer.limit_keys, k0))
    return {"opened": ch["opened"], "closed": ch["closed"], "slid": int(seen.size),
            "at_coulomb_limit_reference": ch["at_limit_reference"], "at_coulomb_limit_loaded": ch["at_limit_current"],
            "sampled_every_steps": deck["relax"]["check_every"]}


def per_grain_stress(dM_yy, radius, thickness, solid_fraction):
    """A per-grain stress change [Pa] for pictures: ``dM_yy phi / (pi R^2 t)`` (the grain's share
    of the area is its disk over the packing's solid fraction ``phi``)."""
    return np.asarray(dM_yy) * float(solid_fraction) / (np.pi * np.asarray(radius) ** 2 * float(thickness))


# ---------------------------------------------------------------------------------------------
# the whole protocol

def new_state():
    """The JSON-able state of ``respond`` before it starts (stage ``reference``)."""
    return {"stage": "reference", "start": None, "wave": None, "reference": None, "top0": None,
            "bottom0": None, "force": None, "loaded_gid": None, "loaded_position": None, "dyn_start": None,
            "t_load": None, "dyn_index": 0, "static": None, "point": 0, "point_reference": None}


def respond(layer, deck, progress=None, operations=(), on_row=None, on_record=None, state=None, stop=None,
            clock=None):
    """Steps 4 to 7 on a ``Layer``; returns the results dict on rank 0 (None elsewhere).
    ``on_row(row)``: every relaxation check (``SERIES_COLUMNS``); ``on_record(label, state,
    result)``: every recorded response (dynamic snapshots and the static one), rank 0 gets the
    gathered state and the measure. Collective.

    Restart: ``state`` (``new_state()``, updated in place: the stage ``reference``, ``dynamic``,
    ``static`` or ``done``, where its relaxation started, the wave speed, the load, the next
    dynamic snapshot) with ``layer.ref`` and ``layer.records`` put back (``restore_response``)
    continues the response where a checkpoint left it, bit for bit on the same ranks. ``stop``:
    ``StepLimit`` at the first check (or snapshot run) at or after this step. ``clock``: a
    ``granular_output.StageClock`` timing the stages."""
    sim = layer.sim
    t0 = time.perf_counter()
    st = new_state() if state is None else state
    if st["wave"] is None:
        c, H = wave_speed(layer)
        d = deck["relax"]["damping"]
        st["wave"] = {"c": c, "H": H, "transit": H / c, "damping": math.pi * c / H if d == "auto" else float(d)}
    c, H, transit = st["wave"]["c"], st["wave"]["H"], st["wave"]["transit"]
    layer.damping = st["wave"]["damping"]
    st.setdefault("point", 0)                   # (states of checkpoints written before load.points)
    st.setdefault("point_reference", st["reference"])
    if progress is not None and st["stage"] == "reference" and st["point"] == 0 and st["start"] is None:
        n = layer.geometry["n_grains"]
        note = tolerance_note(n, relax_tolerance(deck, n), deck["load"]["fraction"])
        if note:
            progress.say(note)
    if layer.records is None:
        layer.records = []

    def check(sim_, b):
        top, bottom = layer.reactions()
        row = {"step": sim_.step_count, "time": sim_.time, "stage": STAGES.index(st["stage"]),
               "unbalanced": b["unbalanced"], "kinetic": b["kinetic"], "top_force": top, "bottom_force": bottom}
        if on_row is not None:
            on_row(row)
        if st["stage"] == "static":          # the load step's relaxation: sample the Coulomb limit
            sample_limit(layer, deck["load"]["friction"])

    def enter(name):
        if clock is not None:
            clock.enter(name, sim.step_count)

    K = deck["load"]["points"]
    if layer.points is None:
        layer.points = []
    if st["stage"] == "done" and sim.comm.bcast(not layer.points if sim.comm.is_root else None):
        # a finished run's checkpoint without its points (written before load.points): measure now
        point = _point_record(layer, deck, st, on_record, "static")
        if sim.comm.is_root:
            layer.points.append(point)
    while st["stage"] != "done":
        p = st["point"]
        if st["stage"] == "reference":
            enter("reference")
            if st["start"] is None:
                st["start"] = sim.step_count
            b, ok, steps = relax_layer(layer, deck, "reference" if p == 0 else f"reference {p + 1}/{K}", progress,
                                       operations, check, start=st["start"], stop=stop)
            info = {"converged": ok, "steps": steps, "unbalanced": b["unbalanced"], "kinetic": b["kinetic"],
                    "pressure": b["pressure"], "mean_contact_force": b["mean_contact_force"],
                    "n_contacts": b["n_contacts"]}
            st["point_reference"] = info
            st["top0"], st["bottom0"] = layer.reactions()
            layer.ref = gather_state(sim)
            if p == 0:
                st["reference"] = info
                st["force"] = deck["load"]["fraction"] * b["mean_contact_force"]
            F = st["force"]          # the same force at every point
            apply_load(layer, F, loaded_grain(layer, p / K))
            layer.limit_keys = np.zeros(0, np.int64) if sim.comm.is_root else None
            position = sim.comm.bcast(layer.ref["x"][layer.loaded_gid].tolist() if sim.comm.is_root else None)
            if p == 0:
                st["loaded_gid"], st["loaded_position"] = layer.loaded_gid, position
            if progress is not None:
                progress.say(f"reference{'' if K == 1 else f' {p + 1}/{K}'}: {steps} steps, unbalanced "
                             f"{b['unbalanced']:.3g}; load F = {F:.4g} N on grain {layer.loaded_gid}"
                             + (f"; c = {c:.4g} m/s, H = {H:.4g} m, damping {layer.damping:.4g} 1/s" if p == 0 else ""))
            if p == 0:
                st["dyn_start"], st["t_load"], st["dyn_index"] = sim.step_count, sim.time, 0
                st["stage"] = "dynamic"
            else:
                st["stage"], st["start"] = "static", sim.step_count
        if st["stage"] == "dynamic":
            # dynamic (undamped) response
            enter("dynamic")
            sim.viscous_damping = 0.0
            times = deck["dynamic"]["times"]
            while st["dyn_index"] < len(times):
                tau = times[st["dyn_index"]]
                target = st["dyn_start"] + int(round(tau * transit / sim.dt))
                while sim.step_count < target:
                    if stop is not None and sim.step_count >= stop:
                        raise StepLimit(f"stopped at step {sim.step_count} (--steps {stop}), dynamic response")
                    end = target if stop is None else min(target, stop)
                    sim.run(end - sim.step_count, list(operations))
                cur = gather_state(sim)
                if cur is not None:
                    cc = cur["contacts"]
                    lim = lr.at_coulomb_limit(cc["normal"], cc["force"], deck["load"]["friction"])
                    layer.limit_keys = np.union1d(np.zeros(0, np.int64) if layer.limit_keys is None
                                                  else layer.limit_keys, lr.pair_keys(cc["gid_i"][lim], cc["gid_j"][lim]))
                res = measure(layer, layer.ref, cur, deck)
                if res is not None:
                    res.update(time_after_load=sim.time - st["t_load"], time_over_transit=tau, step=sim.step_count)
                if on_record is not None:
                    on_record(f"dynamic t = {tau:g} H/c", cur, res)
                if res is not None:
                    res.pop("per_grain", None)
                    layer.records.append(res)
                st["dyn_index"] += 1
            st["stage"], st["start"] = "static", sim.step_count
        if st["stage"] == "static":
            # static response
            enter("static")
            b2, ok2, steps2 = relax_layer(layer, deck, "static" if K == 1 else f"static {p + 1}/{K}", progress,
                                          operations, check, start=st["start"], stop=stop)
            st["static"] = {"converged": ok2, "steps": steps2, "unbalanced": b2["unbalanced"], "kinetic": b2["kinetic"]}
            point = _point_record(layer, deck, st, on_record, f"static {p + 1}/{K}" if K > 1 else "static")
            if sim.comm.is_root:
                # several points: what the average and the per-point record need (not the comparisons)
                layer.points.append(point if K == 1 else {k: point[k] for k in POINT_KEYS + POINT_BINS})
            if p + 1 < K:
                # the load off (its fix stays, with no force, until the next grain takes it); the
                # packing relaxes to the next point's reference
                layer.load.force[:] = 0.0
                layer.force = 0.0
                st["point"], st["stage"], st["start"] = p + 1, "reference", sim.step_count
            else:
                st["stage"] = "done"
    if clock is not None:
        clock.close(sim.step_count)
    if not sim.comm.is_root:
        return None
    F = st["force"]
    points = layer.points
    last = points[-1]
    if K == 1:
        static = {k: v for k, v in last.items() if k not in ("reference", "static", "bottom_share", "top_share",
                                                               "force", "loaded_gid", "loaded_position")}
        static.update(st["static"])
    else:
        static = average_points(points, layer.geometry, deck["comparison"]["poisson"])
        static.update(converged=all(q["static"]["converged"] for q in points),
                      steps=int(sum(q["static"]["steps"] for q in points)),
                      unbalanced=max(q["static"]["unbalanced"] for q in points),
                      kinetic=max(q["static"]["kinetic"] for q in points))
        static["linear"] = average_points([q["linear"] for q in points], layer.geometry, deck["comparison"]["poisson"])
        static["contact_changes"] = {k: int(sum(q["contact_changes"][k] for q in points))
                                     for k in points[0]["contact_changes"] if k != "sampled_every_steps"}
        static["contact_changes"]["sampled_every_steps"] = deck["relax"]["check_every"]
    out = {"force": F, "loaded_gid": st["loaded_gid"], "loaded_position": st["loaded_position"],
           "wave_speed": c, "height": H, "transit_time": transit, "damping": layer.damping,
           "force_tolerance": relax_tolerance(deck, layer.geometry["n_grains"]),
           "reference": st["reference"],
           "static": static,
           "dynamic": list(layer.records),
           "reactions": {"top_share": float(np.mean([q["top_share"] for q in points])),
                         "bottom_share": float(np.mean([q["bottom_share"] for q in points])),
                         "top_reference": st["top0"], "bottom_reference": st["bottom0"]},
           "geometry": {k: v for k, v in layer.geometry.items() if k not in ("y", "radius")},
           "seconds": time.perf_counter() - t0, "_per_grain": layer.last_per_grain}
    if K > 1:
        out["static_points"] = [{k: q[k] for k in POINT_KEYS} for q in points]
    return out


def _point_record(layer, deck, st, on_record, label):
    """Measure the static response of the current load point (collective); rank 0 gets the
    record (``measure``'s, with the point's relaxations, the rows' shares of F, the force and the
    bins), None elsewhere; its per-grain fields go to ``on_record`` and ``layer.last_per_grain``."""
    top1, bottom1 = layer.reactions()
    cur = gather_state(layer.sim)
    res = measure(layer, layer.ref, cur, deck)
    if on_record is not None:
        on_record(label, cur, res)
    if res is None:
        return None
    layer.last_per_grain = res.pop("per_grain")
    F = st["force"]
    res.update(reference=st["point_reference"], static=st["static"], force=F,
               top_share=-(top1 - st["top0"]) / F, bottom_share=-(bottom1 - st["bottom0"]) / F,
               contact_changes=contact_changes(layer, layer.ref, cur, deck),
               linear=linear_measure(layer, layer.ref, deck))
    return res


__all__ = ["SCHEMA", "RUN_STAGES", "RigidRow", "Layer", "prepared", "make_layer", "respond", "measure", "gather_state",
           "contact_table", "apply_load", "relax_layer", "wave_speed", "iso_deck", "SERIES_COLUMNS", "new_state",
           "layer_state", "restore_layer", "response_arrays", "restore_response", "boundary_conditions",
           "reference_network", "static_linear", "linear_state", "linear_measure", "sample_limit", "contact_changes"]
