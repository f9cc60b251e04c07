"""Bond rupture in the engine: a compact column compressed until its bonds break.

Checks, through the compress driver on 1 and 2 ranks:
* bonds break (tension and shear) and the reducer counts them: the series' cumulative count equals
  the number of broken bonds in the final checkpoint, and the per-step counts add up to it;
* a broken bond's pair then interacts by contact: no intact bonded pair is in a contact list, and
  broken pairs that close up are (with history);
* 1 and 2 ranks agree (the same bonds break, positions to 1e-8) up to the onset of fracture;
* a restart from a checkpoint taken while bonds break is bit for bit (broken bonds, plastic
  strains, contact lists and histories restored);
* the ParaView snapshot shows the broken bonds (``state``), as many as the series counts.
"""
import json
import os
import shutil
import subprocess
import sys

import h5py
import meshio
import numpy as np
import pytest

from _util import ran_to_end

from pardem.engine.contacts import pair_keys
from pardem.io.series import read_series

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
COLUMN = ["--set", "domain.kind=compact", "--set", "domain.box=[0.012, 0.003, 0.003]",
          "--set", "domain.radius=0.25e-3", "--set", "domain.seed=2", "--set", "loading.strain=0.02",
          "--set", "bonds.tensile_strength=0.4e6", "--set", "bonds.shear_strength=0.4e6",
          "--set", "checkpoint.every_steps=1000", "--set", "checkpoint.keep=20"]
STEPS = 9000            # past the force peak: a few hundred bonds broken
EARLY = 6000            # the onset of fracture (tens of bonds)


def driver(n, args, timeout=600):
    cmd = ([MPIEXEC, "-n", str(n)] if n > 1 else []) + [sys.executable, "-m", "pardem.drivers.compress",
                                                        "--quiet", *args]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert ran_to_end(p), p.stderr
    return p


def checkpoint(d, step):
    return d / "checkpoints" / f"checkpoint-{step:010d}.h5"


def by_gid(path, group):
    with h5py.File(path, "r") as f:
        o = np.argsort(f[group]["gid"][...])
        return {k: f[group][k][...][o] for k in f[group] if k != "x_build"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rupture")
    out = {}
    for n in (1, 2):
        out[n] = tmp / f"n{n}"
        driver(n, COLUMN + ["--steps", str(STEPS), "--out", str(out[n]),
                            "--set", f"output.vtk_every={STEPS}"])
    return out


@pytest.mark.mpi
def test_bonds_break_and_are_counted(runs):
    for n, d in runs.items():
        s = read_series(d / "series.csv")
        bonds = by_gid(checkpoint(d, STEPS), "bonds")
        broken = int(np.count_nonzero(bonds["state"]))
        assert broken > 100, f"{n} ranks: only {broken} broken bonds"
        assert s["bonds_broken"][-1] == broken
        assert set(np.unique(bonds["state"])) == {0, 1, 2}      # both tension and shear breaks
        counts = np.array(s["bonds_broken"])
        assert np.all(np.diff(counts) >= 0) and counts[0] == 0
        summary = json.loads((d / "summary.json").read_text())
        assert summary["bonds_broken"] == broken


@pytest.mark.mpi
def test_broken_pairs_interact_by_contact(runs):
    for n, d in runs.items():
        path = checkpoint(d, STEPS)
        bonds = by_gid(path, "bonds")
        intact = pair_keys(bonds["gid_i"][bonds["state"] == 0], bonds["gid_j"][bonds["state"] == 0])
        broken = pair_keys(bonds["gid_i"][bonds["state"] != 0], bonds["gid_j"][bonds["state"] != 0])
        with h5py.File(path, "r") as f:
            keys = pair_keys(f["contacts/gid_i"][...], f["contacts/gid_j"][...])
            history = f["contacts/history"][...]
        assert not np.any(np.isin(keys, intact))
        touching = np.isin(keys, broken) & np.any(history != 0.0, axis=1)
        assert touching.sum() > 10, f"{n} ranks: {touching.sum()} broken pairs in contact"


@pytest.mark.mpi
def test_one_and_two_ranks_agree_at_the_onset_of_fracture(runs):
    a, b = by_gid(checkpoint(runs[1], EARLY), "elements"), by_gid(checkpoint(runs[2], EARLY), "elements")
    assert np.abs(a["x"] - b["x"]).max() <= 1e-8 * np.abs(a["x"]).max()
    A, B = by_gid(checkpoint(runs[1], EARLY), "bonds"), by_gid(checkpoint(runs[2], EARLY), "bonds")
    assert np.count_nonzero(A["state"]) > 5
    assert np.array_equal(A["state"], B["state"])


@pytest.mark.mpi
@pytest.mark.parametrize("n", [1, 2])
def test_restart_while_bonds_break_is_bit_for_bit(runs, tmp_path, n):
    ref = runs[n]
    start = 7000
    assert np.count_nonzero(by_gid(checkpoint(ref, start), "bonds")["state"]) > 0
    driver(n, ["--restart", str(checkpoint(ref, start)), "--steps", str(STEPS), "--out", str(tmp_path)])
    for g in ("elements", "bonds"):
        A, B = by_gid(checkpoint(ref, STEPS), g), by_gid(checkpoint(tmp_path, STEPS), g)
        for k in A:
            assert np.array_equal(A[k], B[k]), f"/{g}/{k}"
    with h5py.File(checkpoint(ref, STEPS)) as fa, h5py.File(checkpoint(tmp_path, STEPS)) as fb:
        for k in ("gid_i", "gid_j", "history"):
            assert np.array_equal(fa["contacts"][k][...], fb["contacts"][k][...]), k
    assert read_series(ref / "series.csv") == read_series(tmp_path / "series.csv")


def test_paraview_shows_the_broken_bonds(runs):
    d = runs[1]
    pieces = sorted((d / "paraview").glob(f"snapshot-{STEPS:08d}-r*.vtu"))
    assert pieces
    state = np.concatenate([meshio.read(p).cell_data["state"][0] for p in pieces])
    assert np.count_nonzero(state) == read_series(d / "series.csv")["bonds_broken"][-1]
    assert os.path.exists(d / "paraview" / "pardem.pvd")
