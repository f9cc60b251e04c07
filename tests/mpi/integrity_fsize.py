"""Run under mpiexec (2 ranks): argv[1] a directory, argv[2] "mpio" or "serial". With the file size
limited to 1 MiB (RLIMIT_FSIZE, write(2) then fails with EFBIG), a small checkpoint is written, then
one too large; prints each rank's OutputError. Exit 0 unless something else went wrong."""
import os
import resource
import signal
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from test_checkpoint_integrity import _payload  # noqa: E402

from pardem.errors import OutputError  # noqa: E402
from pardem.io.checkpoint import write_checkpoint  # noqa: E402
from pardem.parallel.communicator import Communicator  # noqa: E402

comm = Communicator()       # MPI's own shared-memory files are created before the limit
comm.allgather(b"x" * (1 << 20))   # (and its message pools grown)
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)      # EFBIG instead of the signal's default kill
resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))
folder, mode = sys.argv[1], sys.argv[2]
write_checkpoint(os.path.join(folder, "small.h5"), comm, *_payload(20 + comm.rank, first_gid=100000 * comm.rank), mode=mode)
line = f"{comm.rank} no error"
try:
    write_checkpoint(os.path.join(folder, "big.h5"), comm, *_payload(20000 + comm.rank, step=2, first_gid=100000 * comm.rank), mode=mode)
except OutputError as err:
    line = f"{comm.rank} OutputError: {err}"
lines = comm.gather(line)   # rank 0 prints all: lines of two processes may interleave
if comm.is_root:
    sys.stdout.write("".join(f"{v}\n" for v in lines))
    sys.stdout.flush()
