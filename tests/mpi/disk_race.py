"""A disk that fills up while a checkpoint is written. Run as: disk_race.py DIR REF WHEN MODE, with
DIR a small file system of its own (a tmpfs), REF a folder on another one, under mpiexec -n 2 for
MODE "mpio" or "serial", alone for "one".

Writes checkpoint 1, then checkpoint 2 (about 1 MB a rank) with the disk filled by this process in
the middle: WHEN "after_probe" right after the space probe (``checkpoint._reserve``), leaving
6,000 bytes free (HDF5 can create the file but not fill it); "after_hold" right after the space is
reserved in the new file (``checkpoint._hold``), leaving nothing free. Rank 0 prints each rank's
outcome, the folder's files, the steps of the checkpoints that verify, and for checkpoint 2 its
size, its allocated bytes and whether it equals, byte for byte, the same payload written to REF
with nothing filling the disk. Exit 0 unless something else went wrong (HDF5 crashing is a
failure)."""
import filecmp
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from test_checkpoint_integrity import _payload  # noqa: E402

from pardem.errors import OutputError  # noqa: E402
from pardem.io import checkpoint  # noqa: E402
from pardem.parallel.communicator import Communicator  # noqa: E402

folder, ref_dir, when, mode = sys.argv[1:5]
mode = "serial" if mode == "one" else mode
comm = Communicator()


def fill(left):
    """Fill ``folder``'s file system until at most ``left`` bytes are free."""
    fd = os.open(os.path.join(folder, "filler"), os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    for chunk in (1 << 16, 4096, 512, 1):
        try:
            while True:
                st = os.statvfs(folder)
                if st.f_bavail * st.f_frsize - chunk < left:
                    break
                os.write(fd, b"\0" * chunk)
        except OSError:       # ENOSPC: this chunk no longer fits
            pass
    os.close(fd)


def filling_after(name, left):
    """``checkpoint.<name>`` made to fill the disk when it returns; returns the original."""
    real = getattr(checkpoint, name)

    def then_fill(*args, **kwargs):
        out = real(*args, **kwargs)
        fill(left)
        return out
    setattr(checkpoint, name, then_fill)
    return real


first = os.path.join(folder, checkpoint.checkpoint_name(1))
second = os.path.join(folder, checkpoint.checkpoint_name(2))
checkpoint.write_checkpoint(first, comm, *_payload(20 + comm.rank, step=1, first_gid=100000 * comm.rank), mode=mode)
payload = _payload(4000 + comm.rank, step=2, first_gid=100000 * comm.rank)
name, left = {"after_probe": ("_reserve", 6000), "after_hold": ("_hold", 0)}[when]
real = filling_after(name, left)
line = f"{comm.rank} no error"
try:
    checkpoint.write_checkpoint(second, comm, *payload, mode=mode)
except OutputError as err:
    line = f"{comm.rank} OutputError: {err}"
setattr(checkpoint, name, real)
lines = comm.gather(line)
reference = os.path.join(ref_dir, checkpoint.checkpoint_name(2))
checkpoint.write_checkpoint(reference, comm, *payload, mode=mode)
if comm.is_root:
    out = [*lines, "files " + " ".join(sorted(os.listdir(folder)))]
    for path in (first, second):
        if os.path.exists(path):
            out.append(f"verified {os.path.basename(path)} step {int(checkpoint.inspect(path)['step'])}")
    if os.path.exists(second):
        st = os.stat(second)
        out.append(f"size {st.st_size} allocated {st.st_blocks * 512} "
                   f"identical {filecmp.cmp(second, reference, shallow=False)}")
    sys.stdout.write("".join(f"{v}\n" for v in out))
    sys.stdout.flush()
