"""Cementation of the current contacts of a granular case (docs/physics.md section 8, G ch. 7).

Every listed pair in contact (overlap ``delta > 0``) gets an intact cement: ``delta0 = delta`` (the
springs start unstressed), a zero cement tangential force and a rupture energy ``E_th`` drawn from the
uniform distribution on ``[mean - half_width, mean + half_width]`` [J]. The history layout is that of
``pardem.physics.hertz_mindlin`` (cemented, 9 columns); the contacts must already use cemented
parameters (``granular.set_contact_params``).

Thresholds do not depend on the number of ranks or on the order of the lists: each is a function of
``(seed, gid pair key)`` only, ``u = splitmix64(splitmix64(seed) ^ key) / 2^64`` (a counter-based
generator: the SplitMix64 finaliser of Steele, Lea and Flood, OOPSLA 2014), so a pair held by two
ranks (one end a ghost) gets bitwise the same cement on both, and 1 and N ranks agree.

Reach: a cement must not survive a gap as large as the Verlet skin, or a list rebuild could drop the
pair while intact (``pardem.engine.contacts``). Its normal stretch at rupture is at most
``sqrt(2 E_th,max / Sn)`` (the energy's normal part alone), so ``cement_contacts`` refuses
``sqrt(2 (mean + half_width) / Sn) >= skin``.

Strength: pulled apart along the line of centres (no tangential cement force), a cement of rupture
energy ``E_th`` breaks at the stretch ``sqrt(2 E_th / Sn)``, i.e. when its tension reaches
``F* = sqrt(2 Sn E_th)`` [N] once the grains are apart (``tensile_strength``); a tangential load
lowers it (the energy adds ``|f_ct|^2 / (2 St)``).

2D mode (``pardem.engine.plane``): nothing changes. The cement law is the 3D one; for grains in
the plane z = 0 (``v_z = w_x = w_y = 0``) every pair normal lies in the plane, so the cement's normal
and tangential forces lie in it and its torques are along z, and the same calls cement a 2D packing
(``tests/test_two_d_walls_cement.py``: a 2D run is the 3D run of the planar configuration bit for
bit, rupture at ``F*``, 1 vs 2 ranks, restart).
"""
import numpy as np

from pardem.physics import hertz_mindlin as hm
from pardem.physics.contact_frame import pair_geometry

_M64 = (1 << 64) - 1


def _splitmix64(z):
    """SplitMix64 finaliser of uint64 array ``z`` (wrapping arithmetic)."""
    with np.errstate(over="ignore"):
        z = (z + np.uint64(0x9E3779B97F4A7C15))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def pair_uniform(seed, keys):
    """Uniform numbers in [0, 1) [n], one per int64 pair key, a function of ``(seed, key)`` only."""
    s = _splitmix64(np.array([int(seed) & _M64], dtype=np.uint64))[0]
    z = _splitmix64(np.asarray(keys, dtype=np.int64).astype(np.uint64) ^ s)
    return (z >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def thresholds(seed, keys, mean, half_width):
    """Rupture energies [J] of the pairs ``keys``: uniform on ``mean +- half_width``."""
    return float(mean) + float(half_width) * (2.0 * pair_uniform(seed, keys) - 1.0)


def max_stretch(params, mean, half_width):
    """Largest normal stretch ``|delta - delta0|`` [m] an intact cement can reach."""
    return float(np.sqrt(2.0 * (float(mean) + float(half_width)) / params.cement_normal))


def tensile_strength(params, threshold):
    """Tension [N] at which a cement of rupture energy ``threshold`` [J] (scalar or array) breaks
    under a pure normal pull with the grains apart: ``sqrt(2 Sn E_th)``."""
    return np.sqrt(2.0 * float(params.cement_normal) * np.asarray(threshold, dtype=np.float64))


def check(params, mean, half_width, skin):
    """ValueError unless the cement parameters are usable with a Verlet ``skin`` [m]."""
    if not getattr(params, "cemented", False):
        raise ValueError("cementation needs Hertz-Mindlin contacts with cement_normal > 0 [N/m]")
    if not (np.isfinite(mean) and np.isfinite(half_width) and 0.0 <= half_width < mean):
        raise ValueError(f"cement thresholds: mean = {mean} J, half_width = {half_width} J: expected "
                         "0 <= half_width < mean (every threshold positive)")
    x = max_stretch(params, mean, half_width)
    if not x < float(skin):
        raise ValueError(f"cement: a cement may stretch by sqrt(2 E_max / Sn) = {x:.4g} m before it "
                         f"breaks, not below the Verlet skin {float(skin):.4g} m: a list rebuild could "
                         "drop an intact cement (raise cement_normal or the skin, or lower the "
                         "thresholds)")


def cement_contacts(sim, mean, half_width, seed):
    """Cement every listed pair in contact on this rank (call on every rank at the same step,
    after a force evaluation). Returns the global number of cements made (each pair once)."""
    c, e = sim.contacts, sim.elements
    check(c.params, mean, half_width, c.skin)
    if c.history.shape[1] != hm.WIDTH_CEMENTED:
        raise ValueError("cement_contacts: the contacts' history is not cemented (set cemented "
                         "parameters first)")
    # the kernels' own overlap (the same bits on both ranks, and delta0 is exactly the
    # overlap the force kernel sees: the cement starts unstressed)
    delta = pair_geometry(c.i, c.j, c.shift, e.x, e.radius)[3]
    glue = (delta > 0.0) & (c.history[:, hm.CEMENT_STATE] == 0.0)
    h = c.history
    h[glue, hm.CEMENT_FORCE:hm.CEMENT_FORCE + 3] = 0.0
    h[glue, hm.CEMENT_DELTA0] = delta[glue]
    h[glue, hm.CEMENT_THRESHOLD] = thresholds(seed, c.keys[glue], mean, half_width)
    h[glue, hm.CEMENT_STATE] = 1.0
    return int(sim.comm.sum(int(np.count_nonzero(glue & c.counted_once(e.n_owned)))))


def cement_counts(sim):
    """Global ``(intact, fading)`` cement counts (collective; each pair counted once)."""
    c = sim.contacts
    if c.history.shape[1] != hm.WIDTH_CEMENTED:
        return 0, 0
    once = c.counted_once(sim.elements.n_owned)
    st = c.history[:, hm.CEMENT_STATE]
    counts = sim.comm.sum(np.array([np.count_nonzero(once & (st > 0.0)),
                                    np.count_nonzero(once & (st < 0.0))], dtype=np.float64))
    return int(round(counts[0])), int(round(counts[1]))
