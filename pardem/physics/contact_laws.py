"""Registry of the sphere-sphere contact laws: one row per law (docs/physics.md section 8).

A row is the law's module; ``ContactLaw`` below is the interface every row provides. The engine
(``pardem.engine.contacts.Contacts``, ``pardem.engine.granular``), the protocols and the deck
choices find a law here by name only.

How to add a law
----------------
1. One file ``pardem/physics/<law>.py`` with:

   * ``Params``: a frozen dataclass that validates its fields in ``__post_init__`` (SI units) and
     derives what the kernel reads (e.g. ``damped``);
   * the per-pair physics as inline Numba functions built on ``contact_frame`` (normal force with
     its damping, tangential force with history and Coulomb cap, e.g. ``update_history``): a
     ``forces`` function of the signature documented in ``pardem.physics.pair_loop``, chosen at
     setup by ``pair_function(params) -> (forces, engaged)`` (sub-models as compile-time
     constants; ``pair_loop.touching`` as ``engaged`` for a law without cohesion) and its float
     constants ``constants(params, dt) -> tuple``;
   * ``history_width``, ``persistent_rows``, ``normal_stiffness``, ``critical_time_step``,
     ``cutoff``, ``deck_params``, ``elastic_normal_force`` (see ``ContactLaw``);
   * ``compute, compute_all_pairs, single = pair_loop.law_interface(pair_function, constants,
     history_width, reads_mass)`` (``reads_mass(params)``: whether ``forces`` reads the masses;
     the loop gathers them only then): the neighbour-list loop, its all-pairs twin and the one-pair diagnostics are
     the shared ones, compiled once per law function.

2. One row in ``LAWS`` below. The deck's ``contacts.law`` choices should be ``("auto", "none",
   *LAWS)``; a law reading new deck keys also needs them in the deck schema.
"""
from typing import Protocol

import dataclasses
import numpy as np

from pardem.physics import hertz_mindlin, hertz_mindlin_rolling, linear_contact
from pardem.physics.arguments import short

LAWS = {
    "hertz_mindlin": hertz_mindlin,
    "linear": linear_contact,
    "hertz_mindlin_rolling": hertz_mindlin_rolling,
}

cement_time_step = hertz_mindlin.cement_time_step


class ContactLaw(Protocol):
    """Interface of a registry row (a law module; ``params`` is an instance of its ``Params``)."""

    Params: type

    def pair_function(self, params):
        """``(forces, engaged)``: the inline Numba per-pair functions of ``pair_loop``."""

    def constants(self, params, dt) -> tuple:
        """Float constants ``c`` read by ``forces`` (dt [s] for rate-dependent ones)."""

    def history_width(self, params) -> int:
        """Columns of a pair's history row (columns 0:3: tangential force on i [N])."""

    def persistent_rows(self, history) -> np.ndarray:
        """Mask [n] of history rows [n, width] a list rebuild must keep (e.g. intact cements)."""

    def normal_stiffness(self, params) -> tuple:
        """``(k_constant [N/m], k_hertz [Pa])``: tangent normal stiffness ``k_constant + k_hertz
        sqrt(R* delta)`` (``timestep.contact_stiffness``, ``Contacts.stiffness``)."""

    def critical_time_step(self, params, radii, density) -> float:
        """Critical step [s] for spheres of radii [n] [m] and density [kg/m^3]."""

    def cutoff(self, params, rmax) -> float:
        """Largest interacting centre distance [m] for radii <= ``rmax`` [m]."""

    def deck_params(self, section, auto) -> dict:
        """``Params`` keywords from a deck's ``contacts`` section; ``auto[key]()`` gives the value
        of a key set to ``"auto"``."""

    def elastic_normal_force(self, params, r_i, r_j, delta) -> np.ndarray:
        """Elastic normal force [N] [n] of contacts of radii [n] [m] at overlaps [n] [m]."""

    def compute(self, params, elements, i, j, history, dt, shift=None, rate=None, acc=None,
                with_energy=True) -> float:
        """Pair-list forces added to ``elements.f``, ``.t``; elastic energy [J]
        (``pair_loop.law_interface``)."""

    def compute_all_pairs(self, params, elements, history_full, dt) -> float:
        """All-pairs twin of ``compute`` (tests)."""

    def single(self, params, elements, i, j, history_row, dt, shift=(0.0, 0.0, 0.0)) -> dict:
        """Loads of one pair (diagnostics)."""


def law(name) -> ContactLaw:
    """The registry row of law ``name``; ValueError for an unknown name (listing the known ones)."""
    if not isinstance(name, str) or name not in LAWS:
        raise ValueError(f"contact law {short(name)}: expected one of {', '.join(LAWS)}")
    return LAWS[name]


def law_params(name, params):
    """The ``Params`` of law ``name`` from a dict of its keywords (checked there: an unknown key
    lists the valid ones)."""
    row = law(name)
    if not isinstance(params, dict) or not all(isinstance(k, str) for k in params):
        raise ValueError(f"params of contact law {name!r} must be a dict of "
                         f"{row.__name__.rsplit('.', 1)[-1]}.Params keywords (names as strings), got "
                         f"{short(params)}")
    missing = [f.name for f in dataclasses.fields(row.Params) if f.init and f.name not in params
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ValueError(f"params of contact law {name!r}: missing {', '.join(missing)}")
    return row.Params(**params)


def critical_time_step(name, params, radii, density):
    """The contact law's critical step [s] for spheres of radii [n] [m] and density [kg/m^3]."""
    return law(name).critical_time_step(params, radii, density)
