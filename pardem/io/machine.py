"""Facts about this machine read from the operating system (memory available to a run)."""
import os


def available_memory():
    """Bytes of memory available to a new process on this machine (``MemAvailable`` of
    /proc/meminfo, else the free physical pages), or None when unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None
