"""The static moduli of a packing without a backbone (no grain with two contacts: a gas, as an
isotropic preparation capped by ``preparation.max_steps`` before it jams leaves): none, on every
rank, instead of the linear response's ValueError escaping as a traceback (found by the deck
fuzz's small mixture run, whose preparation is capped at 200 steps)."""
import numpy as np

import pardem
from pardem.protocols import moduli_check

R = 1e-4
MATERIAL = {"shear_modulus": 30e9, "poisson": 0.2, "friction": 0.3}


def _gas(gap):
    """27 grains on a cubic lattice of spacing 2 R + ``gap`` in a periodic box (3 per edge)."""
    g = np.arange(3) * (2 * R + gap)
    pos = np.array([[x, y, z] for x in g for y in g for z in g])
    system = pardem.System(pardem.Particles(pos, R, 2500.0),
                           contacts=pardem.ContactModel("hertz_mindlin", {"young": 72e9, "poisson": 0.2,
                                                                          "friction": 0.0, "restitution": 1.0}),
                           cell=pardem.Cell(lo=[-R - 0.5 * gap] * 3, length=[3 * (2 * R + gap)] * 3))
    sim = pardem.build(pardem.Communicator(), system)
    sim.run(0)
    return sim


def test_a_gas_has_no_static_moduli():
    assert moduli_check.static_moduli(_gas(0.1 * R), MATERIAL) is None


def test_a_compressed_lattice_has_them():
    """The same lattice overlapping by 1e-3 R: every grain has 6 contacts, a backbone; its bulk
    modulus is positive (a positive control of the backbone test above)."""
    out = moduli_check.static_moduli(_gas(-1e-3 * R), MATERIAL)
    assert out is not None and out["tangent"]["K_relaxed"] > 0.0
