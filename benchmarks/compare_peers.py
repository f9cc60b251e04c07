"""pardem against its peers, side by side in one run (issue 14): GRAN and GRAN-SHEAR against
LAMMPS, BOND against ESyS-Particle, interleaved A B A B A B (best of ``--repeats``), on this
machine, now.

    python benchmarks/compare_peers.py                       # n = 40, 1 and 2 ranks, GRAN + BOND
    python benchmarks/compare_peers.py --sizes 40 60 --ranks 1 2 --repeats 3
    python benchmarks/compare_peers.py --cases gran --sizes 20 --steps 200 --repeats 1   # smoke test
    python benchmarks/compare_peers.py --cases shear --shear-n 64000 --ranks 1 2   # GRAN-SHEAR

Writes ``results/compare_peers.json`` (every run, with the load seen during it) and
``results/compare_peers.md`` (the table with the ratios and the date); ``--out STEM`` moves both.
Run it on a quiet machine: the host's speed varies by up to 2x between days, so only figures of
one run compare; each run records the CPU time other processes took meanwhile (``other_cores``,
from ``/proc/stat`` minus this job's children), and the table flags rows above 0.15 core. On
one rank the table also gives the ratio of the CPU seconds of the timed steps (pardem:
``time.process_time``; LAMMPS: its loop time times its reported CPU use), which other load
changes much less than the wall time (caches and memory bandwidth are still shared).

The cases are those of ``../shared/peers/CASES.md``, written here from that text:

* GRAN: N = n^3 spheres, R = 0.1 mm, 2500 kg/m^3, E = 72 GPa, Poisson 0.2 (G = 30 GPa),
  friction 0.5, no damping, no gravity; jittered simple cubic lattice (spacing 1.998 R, jitter
  +-0.0002 R, seed 12345; the positions of ``pardem.engine.granular.simple_cubic``, written to the
  LAMMPS data file with 17 digits, so both codes start from the same doubles) in a periodic box
  of side n 1.998 R; dt = 1e-8 s; 100 warm-up then 2000 timed steps. pardem:
  ``benchmarks/bench_gran.py`` (Hertz-Mindlin with tangential history and Coulomb cap, Verlet skin
  0.1 R, rebuilt when an element moved more than skin / 2). LAMMPS: ``pair_style
  gran/hertz/history`` with kn = 4/3 E*, kt = 8 G* (the same Hertz and Mindlin laws), ``fix
  nve/sphere``, ``neighbor 0.1R bin``, ``neigh_modify delay 0 every 1 check yes`` (the same skin
  policy), double precision, newton on; seconds = LAMMPS' own ``Loop time`` of the timed run.
  ``fix nve/sphere`` integrates positions, velocities and spins, not the orientations, and no
  force reads them; pardem's case is built alike (``orientation=False``, the same trajectory to
  the bit) unless ``--gran-orientation on``.
* BOND: n^3 touching spheres, R = 0.25 mm, 1000 kg/m^3, one 6-DOF elastic bond per face pair
  (E = 100 MPa, bond radius R, Poisson 0.3, no damping), frictionless plates normal to x, the one
  at x_max moving at -0.05 m/s; dt = 1e-7 s; 100 warm-up then 2000 timed steps. pardem:
  ``benchmarks/bench_bond.py``. ESyS-Particle: ``RotBondPrms`` with the beam stiffnesses
  (normal E A / L0, shear G A / L0, twist G J / L0, bending 2 E I / L0 since ESyS applies half of
  it), unbreakable, frictionless elastic contacts between unbonded pairs (excluded on bonded
  ones), two elastic walls; one worker rank per pardem rank plus ESyS' master rank; seconds =
  wall time of the timed ``runTimeStep`` loop.

* GRAN-SHEAR (``shear_case.py``): N polydisperse spheres (radii uniform in [0.08, 0.12] mm) of
  the GRAN material in the shared dense random packing ``shear_N.npz`` (rows in a random order),
  sheared at constant volume (pure shear: x at +2000 1/s, y at -2000 1/s, z fixed); dt = 2e-8 s,
  skin 2e-5 m, lists checked every step; 200 warm-up (``--shear-warmup``) then 2000 timed steps.
  pardem: ``benchmarks/bench_shear.py`` (peculiar velocities, the cell's affine motion in the
  contact law; rebuilt when the displacement relative to the affine motion exceeds the skin
  budget). LAMMPS: the GRAN input plus ``fix deform 1 x trate tx y trate ty remap v`` with
  ``trate = ln(1 +- g dt) / dt`` (the same edges as pardem at every step) and lab-frame velocities
  (the peculiar ones plus the streaming velocity about the box centre); it rebuilds when an atom
  moved half the skin in the lab frame (less the box corners' motion). Every rebuild of the timed
  steps is counted in both; the table gives both codes' counts and contacts at the end.

Peers run only when their executables are found (``lmp``, ``esysparticle`` and
``mpirun.openmpi``; Debian packages ``lammps`` and ``esys-particle``, see
``../shared/peers/install.sh``); pardem runs with ``mpiexec.mpich`` on several ranks. Figure of
merit: element-steps per second (N x timed steps / seconds), the larger the better; ratio =
pardem / peer.
"""
import argparse
import datetime
import json
import os
import platform
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import shear_case

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# -- the cases (CASES.md) -------------------------------------------------------------------------

GRAN_R, GRAN_RHO, GRAN_DT = 0.1e-3, 2500.0, 1e-8
GRAN_E, GRAN_NU, GRAN_MU = 72e9, 0.2, 0.5
BOND_R, BOND_RHO, BOND_DT = 0.25e-3, 1000.0, 1e-7
BOND_E, BOND_NU, BOND_V = 100e6, 0.3, 0.05

LAMMPS_INPUT = """\
# GRAN (CASES.md), written by pardem/benchmarks/compare_peers.py
units           si
atom_style      sphere
atom_modify     map array
boundary        p p p
newton          on
comm_modify     vel yes
read_data       {data}
# skin 0.1 R; rebuilt as soon as some sphere moved more than skin / 2 (pardem's policy)
neighbor        {skin:.17g} bin
neigh_modify    delay 0 every 1 check yes
# Hertz: Fn = kn sqrt(R* delta) delta, kn = 4/3 E*; Mindlin: Ft = -kt sqrt(R* delta) s, kt = 8 G*,
# |Ft| <= mu Fn; no damping (gamma_n = gamma_t = 0)
pair_style      gran/hertz/history {kn:.17g} {kt:.17g} 0.0 0.0 {mu} 0
pair_coeff      * *
timestep        {dt:.17g}
fix             integrate all nve/sphere
thermo_style    custom step atoms ke
thermo_modify   norm no
thermo          0
run             {warm}
print           "COMPARE_PEERS timed"
run             {steps}
"""

LAMMPS_SHEAR_INPUT = """\
# GRAN-SHEAR (CASES.md), written by pardem/benchmarks/compare_peers.py
units           si
atom_style      sphere
atom_modify     map array
boundary        p p p
newton          on
comm_modify     vel yes
read_data       {data}
# skin 2e-5 m, checked every step (LAMMPS measures displacements in the lab frame)
neighbor        {skin:.17g} bin
neigh_modify    delay 0 every 1 check yes
pair_style      gran/hertz/history {kn:.17g} {kt:.17g} 0.0 0.0 {mu} 0
pair_coeff      * *
timestep        {dt:.17g}
fix             integrate all nve/sphere
# pure shear at constant volume: L(t) = L0 exp(trate t) = L0 (1 +- g dt)^n, centre fixed
fix             shear all deform 1 x trate {tx:.17g} y trate {ty:.17g} remap v
compute         touch all contact/atom
compute         ntouch all reduce sum c_touch
variable        nc equal c_ntouch/2
thermo_style    custom step atoms ke c_ntouch
thermo_modify   norm no
thermo          0
run             {warm}
print           "COMPARE_PEERS timed"
run             {steps}
print           "COMPARE_PEERS contacts=${{nc}}"
"""

ESYS_SCRIPT = """\
# BOND (CASES.md) for ESyS-Particle, written by pardem/benchmarks/compare_peers.py
import math, os, time
from esys.lsm import *
from esys.lsm.util import *
from esys.lsm.geometry import *

n, workers = int(os.environ["CP_N"]), int(os.environ["CP_WORKERS"])
warm, steps = int(os.environ["CP_WARM"]), int(os.environ["CP_STEPS"])
R, rho, E, nu, v, dt = {R!r}, {rho!r}, {E!r}, {nu!r}, {v!r}, {dt!r}
L0 = 2.0 * R
G = E / (2.0 * (1.0 + nu))
A, I, J = math.pi * R**2, math.pi * R**4 / 4.0, math.pi * R**4 / 2.0
kn, ks, kt, kb = E * A / L0, G * A / L0, G * J / L0, 2.0 * E * I / L0   # ESyS bends with kb / 2
mass = rho * 4.0 / 3.0 * math.pi * R**3
huge = 1e30
grid = [workers, 1, 1]     # slabs, as pardem
sim = LsmMpi(numWorkerProcesses=workers, mpiDimList=grid)
sim.initNeighbourSearch(particleType="RotSphere", gridSpacing=2.5 * R, verletDist=0.2 * R)
sim.setTimeStepSize(dt)
top = (n - 1) * L0
sim.setSpatialDomain(BoundingBox(Vec3(-3 * R, -3 * R, -3 * R), Vec3(top + 3 * R, top + 3 * R, top + 3 * R)))
index = lambda a, b, c: (a * n + b) * n + c
sim.createParticles([SimpleSphere(centre=Vec3(a * L0, b * L0, c * L0), radius=R, id=index(a, b, c),
                                  tag=1, mass=mass)
                     for a in range(n) for b in range(n) for c in range(n)])
links = []
for a in range(n):
    for b in range(n):
        for c in range(n):
            for da, db, dc in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
                if a + da < n and b + db < n and c + dc < n:
                    links.append(TaggedIdConnection(index(a, b, c), index(a + da, b + db, c + dc), 1))
sim.createConnections(links)
sim.createInteractionGroup(RotBondPrms(name="bonds", normalK=kn, shearK=ks, torsionK=kt, bendingK=kb,
                                       normalBrkForce=huge, shearBrkForce=huge, torsionBrkForce=huge,
                                       bendingBrkForce=huge, tag=1, scaling=False))
sim.createInteractionGroup(RotElasticPrms(name="touch", normalK=kn, scaling=False))
sim.createExclusion(interactionName1="bonds", interactionName2="touch")
sim.createWall(name="low", posn=Vec3(-R, 0, 0), normal=Vec3(1, 0, 0))
sim.createWall(name="high", posn=Vec3(top + R, 0, 0), normal=Vec3(-1, 0, 0))
for wall in ("low", "high"):   # ESyS multiplies a wall's normalK by pi R in 3D
    sim.createInteractionGroup(NRotElasticWallPrms(name=wall + "_w", wallName=wall, normalK=kn / (math.pi * R)))
sim.setNumTimeSteps(warm + steps)
step = Vec3(-v * dt, 0.0, 0.0)
for _ in range(warm):
    sim.moveWallBy("high", step)
    sim.runTimeStep()
t0 = time.time()
for _ in range(steps):
    sim.moveWallBy("high", step)
    sim.runTimeStep()
seconds = time.time() - t0
force = sim.getWallForce("low")
sim.exit()
print("COMPARE_PEERS seconds=%.9g plate_force=%.9g" % (seconds, force[0]))
"""


def lattice_data(n, path):
    """Write the GRAN state (pardem's own ``simple_cubic``) as a LAMMPS ``atom_style sphere`` data
    file; returns the box edge [m]."""
    sys.path.insert(0, ROOT)
    from pardem.engine.granular import simple_cubic
    pos, side = simple_cubic(n, GRAN_R, spacing=1.998, jitter=0.0002, seed=12345)
    with open(path, "w") as fh:
        fh.write(f"GRAN n={n}\n\n{len(pos)} atoms\n1 atom types\n\n")
        for axis in "xyz":
            fh.write(f"0.0 {side:.17g} {axis}lo {axis}hi\n")
        fh.write("\nAtoms # sphere\n\n")
        # id type diameter density x y z
        fh.writelines(f"{k + 1} 1 {2 * GRAN_R:.17g} {GRAN_RHO:.17g} {x:.17g} {y:.17g} {z:.17g}\n"
                      for k, (x, y, z) in enumerate(pos))
    return side


# -- running and timing ---------------------------------------------------------------------------

def _busy_seconds():
    """Busy CPU seconds of the whole machine so far (``/proc/stat``; None where unavailable)."""
    try:
        with open("/proc/stat") as fh:
            v = [int(t) for t in fh.readline().split()[1:]]
        return (sum(v[:8]) - v[3] - v[4]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        return None


def run(cmd, cwd, env=None, timeout=1800):
    """Run ``cmd``; returns (stdout, wall seconds, cores other processes used meanwhile)."""
    b0, r0, t0 = _busy_seconds(), resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    # a session of its own: on a time-out the whole MPI job goes (a peer whose master rank died
    # leaves its workers waiting for ever)
    p = subprocess.Popen(cmd, cwd=cwd, env={**os.environ, **(env or {})}, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise RuntimeError(f"{' '.join(cmd)}: no result after {timeout} s (killed)") from None
    wall = time.perf_counter() - t0
    b1, r1 = _busy_seconds(), resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({p.returncode}):\n{stdout[-2000:]}\n{stderr[-2000:]}")
    others = None
    if b0 is not None and b1 is not None:
        mine = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        others = max(0.0, (b1 - b0) - mine) / wall
    return stdout, wall, others


def pardem_cmd(args, ranks, script):
    py = [args.python, os.path.join(HERE, script)]
    return py if ranks == 1 else [args.mpiexec, "-n", str(ranks)] + py


def run_pardem(args, case, n, ranks, work):
    out = os.path.join(work, f"pardem_{case}_{n}_{ranks}.json")
    script = {"gran": "bench_gran.py", "bond": "bench_bond.py", "shear": "bench_shear.py"}[case]
    if case == "shear":
        cmd = pardem_cmd(args, ranks, script) + ["--n", str(n), "--warmup", str(args.shear_warmup),
                                                 "--steps", str(args.steps), "--out", out]
    else:
        cmd = pardem_cmd(args, ranks, script) + ["--sizes", str(n), "--warmup", str(args.warmup),
                                                 "--steps", str(args.steps), "--out", out]
    if case == "gran":
        cmd += ["--orientation", args.gran_orientation]
    load = os.getloadavg()[0]
    _, _, others = run(cmd, HERE, {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
                                   "PYTHONPATH": os.pathsep.join(filter(None, [ROOT, os.environ.get("PYTHONPATH")]))})
    with open(out) as fh:
        row = json.load(fh)["results"][0]
    extra = {"bytes_per_element": row["bytes_per_element"], "loadavg": load}
    if case in ("gran", "shear"):
        extra.update(rebuilds=row["rebuilds_during_timed_steps"], contacts=row["contacts"])
    return {"seconds": row["seconds"], "cpu_seconds": row.get("cpu_seconds"), "elements": row["elements"],
            "other_cores": others, **extra}


def _lammps_constants():
    e_star = GRAN_E / (2.0 * (1.0 - GRAN_NU**2))
    g = GRAN_E / (2.0 * (1.0 + GRAN_NU))
    g_star = g / (2.0 * (2.0 - GRAN_NU))
    return {"kn": 4.0 / 3.0 * e_star, "kt": 8.0 * g_star, "mu": GRAN_MU}


def run_lammps(args, n, ranks, work, case="gran"):
    d = os.path.join(work, f"lammps_{case}_{n}")
    os.makedirs(d, exist_ok=True)
    data = os.path.join(d, f"{case}.data")
    if case == "shear":
        elements = n
        if not os.path.exists(data):
            shear_case.lammps_data(shear_case.load(n), data)
        tx, ty = shear_case.lammps_trates()
        text = LAMMPS_SHEAR_INPUT.format(data=data, skin=shear_case.SKIN, dt=shear_case.DT, tx=tx, ty=ty,
                                         warm=args.shear_warmup, steps=args.steps, **_lammps_constants())
    else:
        elements = n**3
        if not os.path.exists(data):
            lattice_data(n, data)
        text = LAMMPS_INPUT.format(data=data, skin=0.1 * GRAN_R, dt=GRAN_DT, warm=args.warmup,
                                   steps=args.steps, **_lammps_constants())
    with open(os.path.join(d, f"in.{case}"), "w") as fh:
        fh.write(text)
    log = os.path.join(d, f"log.{ranks}")
    cmd = [args.mpirun_openmpi, "--allow-run-as-root", "--oversubscribe", "-np", str(ranks),
           args.lmp, "-in", f"in.{case}", "-log", log, "-screen", "none", "-nocite"]
    load = os.getloadavg()[0]
    _, _, others = run(cmd, d, {"OMP_NUM_THREADS": "1"})
    with open(log) as fh:
        timed = fh.read().split("COMPARE_PEERS timed", 1)[1]
    m = re.search(r"^Loop time of (\S+) on (\d+) procs for (\d+) steps with (\d+) atoms", timed, re.M)
    if not m or int(m.group(2)) != ranks or int(m.group(3)) != args.steps or int(m.group(4)) != elements:
        raise RuntimeError(f"unexpected LAMMPS log {log}")
    builds = re.search(r"^Neighbor list builds = (\d+)", timed, re.M)
    cpu = re.search(r"^([0-9.]+)% CPU use with", timed, re.M)
    # LAMMPS' own breakdown of the timed loop: Pair, Neigh, Comm, Modify, ... seconds (avg over ranks)
    breakdown = {k: float(v) for k, v in re.findall(r"^(\w+)\s*\|\s*\S+\s*\|\s*(\S+)\s*\|", timed, re.M)
                 if k != "Section"}
    contacts = re.search(r"^COMPARE_PEERS contacts=(\S+)", timed, re.M)
    return {"seconds": float(m.group(1)), "elements": elements, "other_cores": others, "loadavg": load,
            "cpu_seconds": float(m.group(1)) * float(cpu.group(1)) / 100.0 if cpu else None,
            "rebuilds": int(builds.group(1)) if builds else None, "breakdown": breakdown,
            "contacts": int(round(float(contacts.group(1)))) if contacts else None}


def run_esys(args, n, ranks, work):
    d = os.path.join(work, "esys")
    os.makedirs(d, exist_ok=True)
    script = os.path.join(d, "bond.py")
    with open(script, "w") as fh:
        fh.write(ESYS_SCRIPT.format(R=BOND_R, rho=BOND_RHO, E=BOND_E, nu=BOND_NU, v=BOND_V, dt=BOND_DT))
    env = {"CP_N": str(n), "CP_WORKERS": str(ranks), "CP_WARM": str(args.warmup),
           "CP_STEPS": str(args.steps), "OMP_NUM_THREADS": "1"}
    cmd = [args.mpirun_openmpi, "--allow-run-as-root", "--oversubscribe", "-np", str(ranks + 1)]
    for k in env:
        cmd += ["-x", k]
    cmd += [args.esys, script]
    out, _, others = run(cmd, d, env)
    m = re.search(r"^COMPARE_PEERS seconds=(\S+) plate_force=(\S+)", out, re.M)
    if not m:
        raise RuntimeError(f"no result from ESyS-Particle:\n{out[-2000:]}")
    return {"seconds": float(m.group(1)), "elements": n**3, "other_cores": others,
            "plate_force": float(m.group(2))}


PEERS = {"gran": ("LAMMPS gran/hertz/history", "lmp", run_lammps),
         "shear": ("LAMMPS gran/hertz/history", "lmp", lambda args, n, ranks, work: run_lammps(args, n, ranks, work, "shear")),
         "bond": ("ESyS-Particle RotBond", "esys", run_esys)}


def rate(r, steps):
    return r["elements"] * steps / r["seconds"]


def cpu_ratio(row):
    """pardem / peer of the best CPU-time rates of a 1-rank row (the timed steps' CPU seconds: on
    a loaded machine a steadier figure than the wall time; '—' when a code does not report it,
    or on several ranks, where ranks waiting in MPI calls spin and count as busy)."""
    if row["ranks"] != 1 or not row["peer"]:
        return "—"
    cp = [r["elements"] / r["cpu_seconds"] for r in row["pardem"] if r.get("cpu_seconds")]
    cq = [r["elements"] / r["cpu_seconds"] for r in row["peer"] if r.get("cpu_seconds")]
    return f"{max(cp) / max(cq):.2f}" if cp and cq else "—"


def cpu_model():
    """The processor's model name and widest vector extension (``/proc/cpuinfo``; None where
    unavailable): this host has moved between machines (an AVX-512 one on 2026-12-03, an AMD EPYC
    with AVX2 on 2026-12-05), which changes the ratios."""
    try:
        with open("/proc/cpuinfo") as fh:
            info = fh.read()
    except OSError:
        return None
    name = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")), "?")
    flags = next((ln.split(":", 1)[1].split() for ln in info.splitlines() if ln.startswith("flags")), [])
    simd = next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), "")
    return f"{name}, {simd}" if simd else name


CASE_NAMES = {"shear": "GRAN-SHEAR"}


def table(report):
    """Markdown of a report: one row per case, size and rank count, best of the repeats."""
    steps = report["steps"]
    lines = [f"Measured {report['date']} to {report.get('date_end', '?')} on {report['machine']} ({report['cpus']} CPUs"
             f"{', ' + report['cpu'] if report.get('cpu') else ''}), "
             f"interleaved pardem / peer, best of {report['repeats']}; element-steps per second "
             f"({report['warmup']} warm-up, GRAN-SHEAR {report.get('shear_warmup', 200)}, + {steps} timed steps). "
             "Load: largest CPU share other processes took during a run, in cores (> 0.15: the figure is not "
             "valid on its own; the ratio of one row is still a comparison under the same load); loadavg: the "
             "1-minute load average (uptime) before the row's runs, lowest-highest."
             + {"on": " GRAN: pardem integrates the grains' orientations (LAMMPS' nve/sphere does not).",
                "off": " GRAN: neither code integrates the grains' orientations (pardem's orientation=False, "
                       "LAMMPS' nve/sphere)."}.get(report.get("gran_orientation"), ""), "",
             "| case | n | ranks | peer code | peer | pardem | ratio | load | loadavg | ratio of CPU time |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    best = {}
    for row in report["rows"]:
        p = max(rate(r, steps) for r in row["pardem"])
        q = max(rate(r, steps) for r in row["peer"]) if row["peer"] else None
        best[(row["case"], row["n"], row["ranks"])] = (p, q)
        load = max([r["other_cores"] or 0.0 for r in row["pardem"] + row["peer"]])
        flag = " !" if load > 0.15 else ""
        avgs = [r["loadavg"] for r in row["pardem"] + row["peer"] if r.get("loadavg") is not None]
        avg = f"{min(avgs):.1f}-{max(avgs):.1f}" if avgs else "—"
        lines.append(f"| {CASE_NAMES.get(row['case'], row['case'].upper())} | {row['n']} | {row['ranks']} | "
                     f"{row['peer_name']} | {'—' if q is None else f'{q:.3g}'} | {p:.3g} | "
                     f"{'—' if q is None else f'{p / q:.2f}'} | {load:.2f}{flag} | {avg} | {cpu_ratio(row)} |")
    speedups = []
    for (case, n, ranks), (p, q) in sorted(best.items()):
        if ranks > 1 and (case, n, 1) in best:
            p1, q1 = best[(case, n, 1)]
            s = f"| {CASE_NAMES.get(case, case.upper())} | {n} | 1 -> {ranks} | {p / p1:.2f} | "
            s += "— |" if q is None or q1 is None else f"{q / q1:.2f} |"
            speedups.append(s)
    shear = [row for row in report["rows"] if row["case"] == "shear"]
    if shear:
        lines += ["", "GRAN-SHEAR, best run of each code: list builds during the timed steps, contacts at the "
                  "end, and LAMMPS' own breakdown of its loop time (seconds: Pair, Neigh, Comm, Modify, Other).", "",
                  "| N | ranks | pardem rebuilds | LAMMPS rebuilds | pardem contacts | LAMMPS contacts | "
                  "pardem B/element | LAMMPS breakdown |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for row in shear:
            bp = max(row["pardem"], key=lambda r: rate(r, steps))
            bq = max(row["peer"], key=lambda r: rate(r, steps)) if row["peer"] else {}
            br = ", ".join(f"{k} {v:.3g}" for k, v in bq.get("breakdown", {}).items()
                           if k in ("Pair", "Neigh", "Comm", "Modify", "Other"))
            lines.append(f"| {row['n']} | {row['ranks']} | {bp.get('rebuilds')} | {bq.get('rebuilds', '—')} | "
                         f"{bp.get('contacts')} | {bq.get('contacts', '—')} | {bp['bytes_per_element']:.0f} | "
                         f"{br or '—'} |")
    if speedups:
        lines += ["", "| case | n | ranks | pardem speed-up | peer speed-up |",
                  "| --- | --- | --- | --- | --- |"] + speedups
    return "\n".join(lines) + "\n"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", nargs="+", choices=["gran", "bond", "shear"], default=["gran", "bond"])
    p.add_argument("--sizes", type=int, nargs="+", default=[40], help="GRAN, BOND: n (elements per edge)")
    p.add_argument("--shear-n", type=int, nargs="+", default=[64000],
                   help="GRAN-SHEAR: N, spheres of a shared packing shear_N.npz (8000, 64000)")
    p.add_argument("--shear-warmup", type=int, default=200)
    p.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeats", type=int, default=3, help="interleaved pairs per row (best taken)")
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--no-peers", action="store_true", help="time pardem only")
    p.add_argument("--out", default=os.path.join(HERE, "results", "compare_peers"),
                   help="output stem: STEM.json and STEM.md")
    p.add_argument("--python", default=sys.executable)
    p.add_argument("--mpiexec", default=shutil.which("mpiexec.mpich") or "mpiexec",
                   help="MPI launcher of pardem (MPICH)")
    p.add_argument("--mpirun-openmpi", default=shutil.which("mpirun.openmpi") or "mpirun.openmpi",
                   help="MPI launcher of the Debian peers (Open MPI)")
    p.add_argument("--lmp", default=shutil.which("lmp"))
    p.add_argument("--esys", default=shutil.which("esysparticle"))
    p.add_argument("--keep", action="store_true", help="keep the work folder (inputs, logs)")
    p.add_argument("--gran-orientation", choices=["on", "off"], default="off",
                   help="GRAN: let pardem integrate the grains' orientations (default off, as LAMMPS' "
                        "fix nve/sphere, which integrates the spin only)")
    args = p.parse_args()
    for name, v in (("--sizes", args.sizes), ("--ranks", args.ranks), ("--repeats", [args.repeats]),
                    ("--steps", [args.steps])):
        if min(v) < 1:
            p.error(f"{name} must be >= 1")
    if "shear" in args.cases:
        for n in args.shear_n:
            if not os.path.exists(shear_case.packing_path(n)):
                p.error(f"--shear-n {n}: no packing {shear_case.packing_path(n)}")
    if min(args.sizes) < 4:
        p.error("--sizes: n must be >= 4 (a periodic box of n < 4 spheres is shorter than twice the reach)")
    have = {"lmp": args.lmp is not None and shutil.which(args.mpirun_openmpi) is not None,
            "esys": args.esys is not None and shutil.which(args.mpirun_openmpi) is not None}
    work = tempfile.mkdtemp(prefix="compare_peers_")
    report = {"benchmark": "compare_peers", "date": datetime.datetime.now(datetime.timezone.utc)
              .strftime("%Y-%m-%d %H:%M UTC"), "machine": platform.machine(), "cpus": os.cpu_count(),
              "cpu": cpu_model(), "load_before": os.getloadavg(), "warmup": args.warmup, "steps": args.steps,
              "repeats": args.repeats, "gran_orientation": args.gran_orientation,
              "shear_warmup": args.shear_warmup,
              "work": work if args.keep else None, "rows": []}
    try:
        for case in args.cases:
            peer_name, exe, peer_run = PEERS[case]
            use_peer = have[exe] and not args.no_peers
            for n in (args.shear_n if case == "shear" else args.sizes):
                for ranks in args.ranks:
                    row = {"case": case, "n": n, "ranks": ranks,
                           "peer_name": peer_name if use_peer else "(not run)", "pardem": [], "peer": []}
                    for k in range(args.repeats):     # A B A B A B
                        row["pardem"].append(run_pardem(args, case, n, ranks, work))
                        msg = f"{case} n={n} ranks={ranks} #{k + 1}: pardem {rate(row['pardem'][-1], args.steps):.3e}"
                        if use_peer:
                            row["peer"].append(peer_run(args, n, ranks, work))
                            msg += f"  {peer_name} {rate(row['peer'][-1], args.steps):.3e}"
                        print(msg, flush=True)
                    report["rows"].append(row)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    report["load_after"] = os.getloadavg()
    report["date_end"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out + ".json", "w") as fh:
        json.dump(report, fh, indent=2)
    md = table(report)
    with open(args.out + ".md", "w") as fh:
        fh.write(md)
    print(md + f"wrote {args.out}.json and {args.out}.md")


if __name__ == "__main__":
    main()
