"""The states of a beam bond (``Bonds.state``, uint8), written by the force loop
(``pardem.physics.beam``: 0 intact, otherwise how it broke; docs/physics.md section 7) and read by
the outputs. A leaf: it imports nothing."""
import numpy as np

BOND_INTACT, BOND_BROKEN_TENSION, BOND_BROKEN_SHEAR = np.uint8(0), np.uint8(1), np.uint8(2)
