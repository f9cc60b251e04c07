"""Run under mpiexec: the compress driver with its critical time step overstated by a factor
(argv[1]), so that the run blows up; the remaining arguments go to the driver."""
import sys

import pardem.protocols.compression as compression

_true_bound = compression.critical_time_step
compression.critical_time_step = lambda *args: float(sys.argv[1]) * _true_bound(*args)

from pardem.drivers.compress import main  # noqa: E402

sys.exit(main(sys.argv[2:]))
