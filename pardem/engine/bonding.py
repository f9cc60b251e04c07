"""Creating beam bonds between element pairs: geometry, anisotropic properties, damping (the time
constants of the modes and the rotation damping matrix, ``pardem.physics.beam.rotation_damping_table``).

The bond's modulus and radius follow the anisotropy law of ``BeamMaterial`` in the LRT ``frame``
(docs/physics.md sections 2 and 3). Reference vectors are stored in each end's body frame at creation.
"""
from dataclasses import dataclass

import numpy as np

from pardem.physics import anisotropy
from pardem.physics.arguments import choice, is_real, keywords, real, short
from pardem.physics.beam import rotation_damping_table
from pardem.engine.state import Bonds


@keywords("BeamMaterial")
@dataclass(frozen=True)
class BeamMaterial:
    """young [Pa] and radius_ratio (r = ratio * mean(R1, R2)): scalar or (L, R, T) values.

    poisson : bond Poisson ratio, G = E / (2 (1 + poisson)); damping : ratio zeta of each mode.
    tensile_strength, shear_strength [Pa] : rupture thresholds on F / S and |T| / S, scalar or
        (L, R, T) values following ``law`` (docs/physics.md section 7); 0 = unbreakable.
    densification_stress [Pa] : threshold sigma0 of the bonds initially along T (the frame axis
        closest to the bond is T); 0 = elastic. densification_p0 : the factor p0 of section 7.
    """
    young: tuple
    radius_ratio: tuple
    poisson: float
    damping: float
    law: str = "TOR"
    tensile_strength: tuple = 0.0
    shear_strength: tuple = 0.0
    densification_stress: float = 0.0
    densification_p0: float = 0.0

    def __post_init__(self):
        # the fields are kept as given (their bits reach the bonds); only checked here
        choice("BeamMaterial.law", self.law, tuple(anisotropy.LAWS))
        _per_axis("BeamMaterial.young", self.young, "[Pa]", positive=True)
        _per_axis("BeamMaterial.radius_ratio", self.radius_ratio, "(bond radius / mean element radius)",
                  positive=True)
        # G = E / (2 (1 + nu)) needs nu > -1; the deck's range (-1, 0.5) (pardem.config)
        real("BeamMaterial.poisson", self.poisson, lo=-1.0, hi=0.5)
        real("BeamMaterial.damping", self.damping, lo=0.0, lo_open=False, note="damping ratio zeta of each mode")
        _per_axis("BeamMaterial.tensile_strength", self.tensile_strength, "[Pa]", positive=False)
        _per_axis("BeamMaterial.shear_strength", self.shear_strength, "[Pa]", positive=False)
        real("BeamMaterial.densification_stress", self.densification_stress, lo=0.0, lo_open=False,
             unit="[Pa]", note="0: elastic")
        real("BeamMaterial.densification_p0", self.densification_p0, lo=0.0, lo_open=False)

    @property
    def breakable(self):
        return bool(np.any(np.asarray(self.tensile_strength) > 0.0)
                    or np.any(np.asarray(self.shear_strength) > 0.0))

    @property
    def densifies(self):
        return self.densification_stress > 0.0 and self.densification_p0 > 0.0


def _per_axis(name, value, unit, positive):
    """Check a scalar or (L, R, T) property: > 0 (``positive``) or a strength, >= 0 as a scalar (0:
    unbreakable) and a triple all > 0 or all 0 (a zero axis among positive ones would make the
    interpolating laws divide by zero)."""
    note = "" if positive else "0: unbreakable"
    if is_real(value):
        real(name, value, lo=0.0, lo_open=positive, unit=unit, note=note)
        return
    if not (isinstance(value, (list, tuple)) and len(value) == 3
            or isinstance(value, np.ndarray) and value.shape == (3,)):
        raise ValueError(f"{name} = {short(value)}: expected one number or an (L, R, T) triple of numbers "
                         f"{unit}")
    vals = [real(f"{name}[{k}]", v, lo=0.0, lo_open=positive, unit=unit) for k, v in enumerate(value)]
    if not positive and min(vals) == 0.0 < max(vals):
        raise ValueError(f"{name} = {short(value)}: expected all three values > 0 {unit}, or 0 (a single "
                         "number) for no threshold")


def _reference_normal(n):
    """A unit vector normal to each unit row of ``n``, built from the least aligned axis."""
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    p = np.cross(n, axis)
    return p / np.linalg.norm(p, axis=1)[:, None]


def make_bonds(elements, pairs, material, frame, gids=None):
    """Beam bonds joining rows ``pairs`` [n, 2] of ``elements``.

    Ends are ordered by element gid and bonds sorted by (gid_i, gid_j). ``gids`` [n] are the bonds'
    global ids in the order of ``pairs`` (default ``0..n-1`` in sorted order).
    """
    e = elements
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    swap = e.gid[pairs[:, 0]] > e.gid[pairs[:, 1]]
    pairs = np.where(swap[:, None], pairs[:, ::-1], pairs)
    # sorted by first end, then second: the force scatter then walks memory forward
    order = np.lexsort((e.gid[pairs[:, 1]], e.gid[pairs[:, 0]]))
    pairs = pairs[order]
    gids = np.arange(len(pairs), dtype=np.int64) if gids is None else np.asarray(gids, dtype=np.int64)[order]
    i, j = pairs[:, 0], pairs[:, 1]
    d = e.x[j] - e.x[i]
    L0 = np.linalg.norm(d, axis=1)
    if np.any(L0 <= 0.0):
        raise ValueError("a bond joins two elements at the same position")
    n = d / L0[:, None]
    young = anisotropy.evaluate(material.law, n, frame, material.young)
    r_adim = anisotropy.evaluate(material.law, n, frame, material.radius_ratio)
    r = r_adim * 0.5 * (e.radius[i] + e.radius[j])
    with np.errstate(over="ignore", under="ignore"):    # refused below, in one line
        S = np.pi * r**2
        I = np.pi * r**4 / 4.0
        I0 = np.pi * r**4 / 2.0
        G = young / (2.0 * (1.0 + material.poisson))
        ka = young * S / L0
        kb = young * I
        kt = G * I0 / L0
    for name, k in (("axial E S / L0", ka), ("bending E I", kb), ("torsion G I0 / L0", kt)):
        if not np.all(np.isfinite(k) & (k > 0.0)):
            # r**4 leaves the float range near r/R ~ 1e-75 or 1e75: no step could use that bond
            raise ValueError(f"BeamMaterial.young, radius_ratio: a bond's {name} stiffness is "
                             f"{float(k[~(np.isfinite(k) & (k > 0.0))][0]):g}, not a finite positive number; "
                             "keep young * (bond radius)**4 within the float range")
    zeta = material.damping
    m_red = e.mass[i] * e.mass[j] / (e.mass[i] + e.mass[j])
    i_red = e.inertia[i] * e.inertia[j] / (e.inertia[i] + e.inertia[j])
    # tau = c / k = 2 zeta sqrt(m*/k) per mode of the free pair: axial (ES/L0 against m*),
    # relative bending (the ends turning opposite ways: EI/L0 against I*), twist (GI0/L0 against I*)
    tau_a = 2.0 * zeta * np.sqrt(m_red / ka)
    tau_b = 2.0 * zeta * np.sqrt(i_red * L0 / kb)
    tau_t = 2.0 * zeta * np.sqrt(i_red / kt)
    f_tensile = _threshold(material.law, n, frame, material.tensile_strength) * S
    f_shear = _threshold(material.law, n, frame, material.shear_strength) * S
    along_t = np.argmax(anisotropy.direction_angles(n, frame)[0], axis=1) == 2
    f_yield = np.where(along_t, material.densification_stress * S, 0.0) if material.densifies \
        else np.zeros(len(L0))
    p = _reference_normal(n)
    # body-frame copies: R^T v for each end (rot refreshed: a run without bonds skips it per step)
    e.refresh_rotations()
    to_body = lambda rows, vec: np.einsum("kji,kj->ki", e.rot[rows], vec)
    nb = len(i)
    bi, bj = i.astype(np.int32), j.astype(np.int32)
    # the damping of the two end rotations, constant per bond: once here, not every step
    rot_damping = rotation_damping_table(bi, bj, L0, ka, kb, tau_a, e.mass, e.inertia) if zeta > 0.0 \
        else np.zeros((nb, 0))
    return Bonds(
        i=bi, j=bj,
        gid=gids.copy(),
        gid_i=e.gid[i].copy(), gid_j=e.gid[j].copy(),
        L0=L0, ka=ka, kb=kb, kt=kt, tau_a=tau_a, tau_b=tau_b, tau_t=tau_t,
        u1=to_body(i, n), p1=to_body(i, p), u2=to_body(j, n), p2=to_body(j, p),
        young=young, radius=r, state=np.zeros(nb, np.uint8), f_tensile=f_tensile, f_shear=f_shear,
        f_yield=f_yield, plastic=np.zeros(nb), rot_damping=rot_damping, damped=bool(zeta > 0.0),
        breakable=material.breakable,
        densify_p0=float(material.densification_p0) if material.densifies else 0.0,
    )


def _threshold(law, n, frame, strength):
    """Strength [Pa] of each bond direction by the anisotropy law; inf where it is 0 (unbreakable)."""
    if np.all(np.asarray(strength) == 0.0):
        return np.full(len(n), np.inf)
    return anisotropy.evaluate(law, n, frame, strength)
