"""Run under mpiexec: ``inspect(argv[1], comm)`` on every rank; prints "<rank> ok <step>" or
"<rank> <error message>" (the verdict must be the same on every rank, and no rank may hang)."""
import sys

from pardem.io.checkpoint import CheckpointError, inspect
from pardem.parallel.communicator import Communicator

comm = Communicator()
try:
    meta = inspect(sys.argv[1], comm)
    line = f"{comm.rank} ok {int(meta['step'])}"
except CheckpointError as err:
    line = f"{comm.rank} {err}"
# rank 0 prints every rank's verdict: lines written by two processes at once may interleave
lines = comm.gather(line)
if comm.is_root:
    sys.stdout.write("".join(f"{v}\n" for v in lines))
    sys.stdout.flush()
