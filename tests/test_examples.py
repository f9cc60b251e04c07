"""The examples/ scripts, shortened (--quick), as a user runs them; their physics is asserted here
from their printed numbers, not only from their exit status."""
import os
import re
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")


def run(script, *args, ranks=None, timeout=900):
    cmd = [sys.executable, os.path.join(ROOT, "examples", script), *args]
    if ranks is not None:
        cmd = [MPIEXEC, "-n", str(ranks)] + cmd
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    return res


def number(pattern, text):
    m = re.search(pattern, text)
    assert m, f"{pattern!r} not in the output:\n{text}"
    return float(m.group(1))


FLOAT = r"([-+]?\d+\.?\d*(?:e[-+]?\d+)?)"


def cantilever_error(out):
    return number(r"relative error " + FLOAT, out)


def test_cantilever_matches_euler_bernoulli():
    res = run("cantilever.py", "--quick")
    assert res.returncode == 0, res.stdout + res.stderr
    # the discrete chain is an exact Euler-Bernoulli frame: the static tip deflection agrees to
    # the equilibrium residual (the example runs until it changes < 1e-8 per chunk); 1e-6 as the
    # example's own tolerance, derived in its docstring
    assert abs(cantilever_error(res.stdout)) < 1e-6
    assert number(r"clamp reaction " + FLOAT, res.stdout) == pytest.approx(1e-3, rel=1e-6)   # = the load
    assert "PASS" in res.stdout


def test_drop_rebounds_with_the_wall_restitution():
    res = run("drop.py", "--quick", "--restitution", "0.5")
    assert res.returncode == 0, res.stdout + res.stderr
    ratio = number(r"rebound ratio " + FLOAT, res.stdout)
    tol = number(r"tolerance " + FLOAT, res.stdout)
    # the example's bound: gravity during the contact 2 g / (omega v) + discretisation omega dt / 2
    assert abs(ratio - 0.5) <= tol
    assert tol < 0.03          # the bound itself stays meaningful (omega dt = 0.05 in --quick)
    # the impact speed is the free-fall speed (Verlet is exact under constant gravity), to the
    # last step before the contact: g dt ~ 5e-5 m/s
    v_in = number(r"impact speed " + FLOAT, res.stdout)
    v_ff = number(r"free fall " + FLOAT, res.stdout)
    assert v_in == pytest.approx(v_ff, abs=1e-4)


def test_custom_compression_gives_the_lattice_modulus():
    res = run("custom_compression.py", "--quick")
    assert res.returncode == 0, res.stdout + res.stderr
    # 1 %: the compress driver's own tolerance on this modulus (see the example's docstring)
    assert abs(number(r"relative error " + FLOAT, res.stdout)) < 0.01
    # the thermo log ran: 4 lines after a header, of the 6 columns this model has (step, time and
    # the kinetic, bond, wall and total energies: no contacts, so no contact energy column)
    lines = [ln for ln in res.stdout.splitlines() if re.match(r"\s+\d+\s+\d\.\d+e", ln)]
    assert len(lines) == 4 and all(len(ln.split()) == 6 for ln in lines)
    assert res.stdout.split().count("bond") == 1 and "contact" not in res.stdout.split()


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_cantilever_gives_the_same_answer_on_two_ranks():
    one = run("cantilever.py", "--quick")
    two = run("cantilever.py", "--quick", ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    d1 = number(r"tip deflection " + FLOAT, one.stdout)
    d2 = number(r"tip deflection " + FLOAT, two.stdout)
    # same per-element arithmetic on both decompositions (ghosts are exact copies, bonds computed
    # in the same orientation); only summation order may differ: 1e-12 relative over the run
    assert d2 == pytest.approx(d1, rel=1e-12)
    assert abs(cantilever_error(two.stdout)) < 1e-6


@pytest.fixture(scope="module")
def pour_one_rank():
    return run("pour.py", "--quick")


def test_pour_floor_carries_the_weight_and_the_bed_packs_randomly(pour_one_rank):
    res = pour_one_rank
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    assert number(r"kinetic / potential energy lost " + FLOAT, out) < 1e-7      # settled
    # frictionless walls: the floor carries the whole weight, to the momentum bound of the example
    # (2 sqrt(2 M K) / T over the averaging window T, derived in its docstring)
    rel = number(r"relative " + FLOAT, out)
    tol = number(r"tolerance " + FLOAT, out)
    assert abs(rel) <= tol
    assert tol < 5e-3       # the bound itself stays sharp: K < 1e-7 of the potential energy lost
    # a poured bed of frictional spheres: between random loose (0.555, Onoda and Liniger 1990) and
    # random close packing (0.637, Scott and Kilgour 1969)
    phi = number(r"bulk packing fraction " + FLOAT, out)
    assert 0.55 <= phi <= 0.64
    # the layers along the flat walls and the free surface are looser than the bulk
    assert number(r"whole-bed packing fraction " + FLOAT, out) < phi
    assert "PASS" in out


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_pour_gives_the_same_bed_on_two_ranks(pour_one_rank):
    one = pour_one_rank
    two = run("pour.py", "--quick", ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    # reproducible contacts (the default): the same trajectory bits on any rank count, and the
    # settling test reads an exact kinetic energy sum, so the run stops at the same step
    steps = r"(\d+) steps of"
    assert number(steps, two.stdout) == number(steps, one.stdout)
    assert number(r"bulk packing fraction " + FLOAT, two.stdout) == \
        number(r"bulk packing fraction " + FLOAT, one.stdout)
    # the floor force is a float sum over rows, then ranks: it agrees to round-off (n eps ~ 1e-13)
    f1 = number(r"floor force " + FLOAT, one.stdout)
    f2 = number(r"floor force " + FLOAT, two.stdout)
    assert f2 == pytest.approx(f1, rel=1e-12)
    assert "PASS" in two.stdout


@pytest.fixture(scope="module")
def pour_cylinder_one_rank():
    return run("pour_cylinder.py", "--quick")


def test_pour_cylinder_inserts_the_distribution_and_settles(pour_cylinder_one_rank):
    res = pour_cylinder_one_rank
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    # every grain inserted during the run (the first batch at the build), none left without room
    assert number(r"(\d+) spheres inserted", out) == 500
    assert number(r"in (\d+) batches", out) >= 5
    assert number(r"(\d+) without room", out) == 0
    # the radii are a sample of the requested truncated log-normal law (KS against scipy's CDF)
    assert number(r"Kolmogorov-Smirnov p = " + FLOAT, out) > 1e-3
    assert number(r"kinetic / \(M g <R>\) " + FLOAT, out) < 1e-6       # settled
    # frictionless walls: the floor carries the weight, to the momentum bound of examples/pour.py
    rel = number(r"relative " + FLOAT, out)
    tol = number(r"tolerance " + FLOAT, out)
    assert abs(rel) <= tol and tol < 5e-3
    # between random loose packing (0.555) and random close packing of this dispersion (0.65)
    phi = number(r"bulk packing fraction " + FLOAT, out)
    assert 0.55 <= phi <= 0.65
    assert number(r"whole-bed packing fraction " + FLOAT, out) < phi
    assert "PASS" in out


def test_pour_cylinder_wall_holds_the_bed_at_rest(pour_cylinder_one_rank):
    res = pour_cylinder_one_rank
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    assert "cylinder radius" in out
    # every grain inside the cylinder wall, reaching into it by less than the 0.05 r overlap bound
    # of the code's time step (engine.walls.WALL_OVERLAP_BOUND)
    assert number(r"inside the cylinder: (\d+) of", out) == 500
    assert number(r"deepest wall overlap " + FLOAT, out) < 0.05
    # mass conserved: the bed's mass is the sum of the batches' masses as they arrived (two float
    # sums of the same 500 terms in different orders: 1e-12 relative)
    m_bed = number(r"; mass " + FLOAT, out)
    assert number(r"inserted " + FLOAT + " kg", out) == pytest.approx(m_bed, rel=1e-12)
    # the bed's mass from the printed weight M g (g = 9.81 m/s^2): an independent product
    assert number(r"weight M g " + FLOAT, out) == pytest.approx(m_bed * 9.81, rel=1e-12)
    # the walls' total force is (0, 0, -M g) to the momentum bound of velocity Verlet over the
    # window (2 sqrt(2 M K) / T, examples/pour.py); the frictionless cylinder carries no weight
    weight = number(r"weight M g " + FLOAT, out)
    assert number(r"largest difference from \(0, 0, -M g\) " + FLOAT, out) <= number(r"\(tolerance " + FLOAT + " N",
                                                                                     out) < 5e-3 * weight
    fz = number(r"cylinder \(\S+, \S+, " + FLOAT, out)
    assert abs(fz) <= 1e-12 * weight
    # at rest: the kinetic energy stays below the settling threshold over the undamped window
    assert number(r"over the undamped window " + FLOAT, out) < 1e-6
    assert "PASS" in out


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_pour_cylinder_gives_the_same_bed_on_two_ranks(pour_cylinder_one_rank):
    one = pour_cylinder_one_rank
    two = run("pour_cylinder.py", "--quick", ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    # the same particles inserted (one seed, drawn identically on every rank) and the same
    # trajectory bits (reproducible contacts): the same step count, fraction and KS statistic
    for pattern in (r"(\d+) steps of", r"bulk packing fraction " + FLOAT, r"Kolmogorov-Smirnov p = " + FLOAT,
                    r"kinetic / \(M g <R>\) " + FLOAT):
        assert number(pattern, two.stdout) == number(pattern, one.stdout), pattern
    # the floor force is a float sum over rows, then ranks: it agrees to round-off
    assert number(r"floor force " + FLOAT, two.stdout) == pytest.approx(number(r"floor force " + FLOAT, one.stdout),
                                                                       rel=1e-12)
    assert "PASS" in two.stdout


@pytest.fixture(scope="module")
def fracture_one_rank():
    return run("fracture.py", "--quick")


def test_fracture_breaks_at_the_strength_of_a_section(fracture_one_rank):
    res = fracture_one_rank
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    assert number(r"(\d+) bond\(s\)", out) >= 1
    # n_s sigma_t pi r^2 for the 3 x 3 bar: 9 * 1e6 Pa * pi (0.5 mm)^2, computed here independently
    assert number(r"F_rupture = n_s sigma_t pi r\^2 = " + FLOAT, out) == pytest.approx(9 * 1e6 * 3.141592653589793
                                                                                      * 0.5e-3**2, rel=1e-6)
    # the example's bound: wave transit over loading time (x 4), bond damping, one step of the end
    tol = number(r"tolerance " + FLOAT, out)
    assert tol < 0.05
    for measure in (r"clamp reaction \S+ N, relative error ", r"N/m = \S+ N, relative error "):
        assert abs(number(measure + FLOAT, out)) <= tol
    assert "PASS" in out


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_fracture_breaks_at_the_same_step_on_two_ranks(fracture_one_rank):
    one = fracture_one_rank
    two = run("fracture.py", "--quick", ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    # bonds are computed in the same orientation on every rank: the same bits, the same first step
    step = r"first rupture at step (\d+)"
    assert number(step, two.stdout) == number(step, one.stdout)
    r1 = number(r"clamp reaction " + FLOAT, one.stdout)
    r2 = number(r"clamp reaction " + FLOAT, two.stdout)
    # the clamped layer's force: a float sum over ranks, equal to round-off
    assert r2 == pytest.approx(r1, rel=1e-12)
    assert "PASS" in two.stdout


def simple_shear_friction(out):
    return number(r"steady friction mu " + FLOAT, out)


def test_simple_shear_reaches_the_published_steady_friction():
    res = run("simple_shear.py", "--quick")
    assert res.returncode == 0, res.stdout + res.stderr
    # the example's bounds (its docstring: quasi-static mu_s ~ 0.37 for grain friction 0.5,
    # Chialvo, Sun and Sundaresan 2012; widened for 300 grains and 1.6 strain units)
    assert 0.25 <= simple_shear_friction(res.stdout) <= 0.55
    # the normal-stress servo holds sigma_yy at the target (1e5 Pa) within the flow's scatter
    assert number(r"normal stress " + FLOAT, res.stdout) == pytest.approx(1e5, rel=0.1)
    assert number(r"tilt flips " + FLOAT, res.stdout) >= 1
    assert "PASS" in res.stdout


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_simple_shear_gives_the_same_answer_on_two_ranks():
    one = run("simple_shear.py", "--quick")
    two = run("simple_shear.py", "--quick", ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    # reproducible lists and exact sums: the same trajectory, so the same printed friction
    assert simple_shear_friction(one.stdout) == simple_shear_friction(two.stdout)


@pytest.fixture(scope="module")
def drum_one_rank():
    return run("drum.py", "--quick")


def test_drum_flows_at_a_dynamic_angle_of_repose(drum_one_rank):
    res = drum_one_rank
    assert res.returncode == 0, res.stdout + res.stderr
    # the range of the example's docstring (GDR MiDi 2004; Zhou et al. 2002; Taberlet et al. 2003)
    beta = number(r"dynamic angle of repose " + FLOAT, res.stdout)
    assert 15.0 < beta < 45.0
    # the walls carry the weight of a bed in steady flow (centre of mass nearly still)
    assert number(r"walls carry " + FLOAT, res.stdout) == pytest.approx(1.0, abs=0.02)
    assert "PASS" in res.stdout


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_drum_gives_the_same_angle_on_two_ranks(drum_one_rank):
    two = run("drum.py", "--quick", ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    # each grain's wall and contact loads depend on its own state: the same trajectory bits, so
    # the centroid angle, from the gathered positions, prints the same digits
    angle = r"dynamic angle of repose (\S+) deg"
    one_text = re.search(angle, drum_one_rank.stdout).group(1)
    assert re.search(angle, two.stdout).group(1) == one_text
    # the wall forces are float sums over ranks: equal to round-off at the printed 4 digits
    assert number(r"walls carry " + FLOAT, two.stdout) == pytest.approx(
        number(r"walls carry " + FLOAT, drum_one_rank.stdout), abs=2e-4)


def mu_of_i_levels(out):
    """The printed levels of examples/mu_of_i.py: {I_target: (I, P [Pa], mu, stderr)}."""
    rows = re.findall(r"^\s+(\S+)\s+(\S+)\s+\S+\s+\S+\s+(\S+)\s+(\S+)\s+(\S+)\s+\S+\s+\S+\s+\d+$", out, re.M)
    return {float(t): tuple(float(v) for v in rest) for t, *rest in rows}


@pytest.fixture(scope="module")
def mu_of_i_one_rank(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mu_of_i")
    return run("mu_of_i.py", "--quick", "--out", str(folder)), folder


def test_mu_of_i_friction_rises_with_the_inertial_number(mu_of_i_one_rank):
    res, folder = mu_of_i_one_rank
    assert res.returncode == 0, res.stdout + res.stderr
    levels = mu_of_i_levels(res.stdout)
    assert sorted(levels) == [0.01, 0.3]
    (i_lo, p_lo, mu_lo, e_lo), (i_hi, p_hi, mu_hi, e_hi) = levels[0.01], levels[0.3]
    # the servo holds the normal stress at 1e5 Pa: the measured I is the target within the flow's
    # scatter of P (a few percent: I ~ P^(-1/2))
    for p in (p_lo, p_hi):
        assert p == pytest.approx(1e5, rel=0.05)
    assert i_lo == pytest.approx(0.01, rel=0.03) and i_hi == pytest.approx(0.3, rel=0.03)
    # what a short run can show: mu at I = 0.3 above mu at I = 0.01 by twice their combined block
    # standard error (the example's --quick criterion; the published law gives a rise of ~0.1)
    assert mu_hi - mu_lo > 2.0 * (e_lo ** 2 + e_hi ** 2) ** 0.5
    # dense frictional flow: both in the range of steady friction of grains of friction 0.5
    # (0.3-0.6: quasi-static ~0.37 to ~0.5 at I = 0.3, Jop et al. 2006), far from frictionless ~0.1
    assert 0.3 < mu_lo < mu_hi < 0.6
    # the CSV carries units and the printed values; the figure is written
    text = (folder / "mu_of_i.csv").read_text().splitlines()
    assert text[0].startswith("# I_target [-], I [-], gamma_dot [1/s], tau [Pa], P [Pa], mu [-]")
    rows = [[float(v) for v in line.split(",")] for line in text[1:]]
    assert [r[0] for r in rows] == [0.01, 0.3]
    assert rows[0][5] == pytest.approx(mu_lo, abs=1e-6) and rows[1][5] == pytest.approx(mu_hi, abs=1e-6)
    assert rows[1][3] / rows[1][4] == pytest.approx(rows[1][5], rel=1e-9)      # mu = tau / P
    assert (folder / "mu_of_i.png").stat().st_size > 1000
    assert "PASS" in res.stdout


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_mu_of_i_gives_the_same_curve_on_two_ranks(mu_of_i_one_rank, tmp_path):
    one, folder = mu_of_i_one_rank
    two = run("mu_of_i.py", "--quick", "--out", str(tmp_path), ranks=2)
    assert two.returncode == 0, two.stdout + two.stderr
    assert "2 rank(s)" in two.stdout
    # reproducible lists and exact stress sums, the kinetic stress from the gathered rows in gid
    # order: the same trajectory bits, so the same CSV to the last printed digit
    assert mu_of_i_levels(two.stdout) == mu_of_i_levels(one.stdout)
    assert (tmp_path / "mu_of_i.csv").read_text() == (folder / "mu_of_i.csv").read_text()
