"""Task farm: the ranks of a job share out independent cases (realisations, parameter points).

Case k of the list runs on rank ``k % size``, alone (each case gets a communicator of its rank,
``Communicator.split_self``), so a case's result is the same bits on any number of ranks: it never
sees the decomposition. A static round robin, not a queue: no rank waits on a master, and a case's
rank is known in advance (a study can check its first case on the rank that will run it).
"""


def owner(index, size):
    """The rank that runs case ``index`` of a farm on ``size`` ranks."""
    return int(index) % int(size)


def run_cases(comm, cases, run_one, finished=None, key=None, on_record=None):
    """Collective: run this rank's share of ``cases`` with ``run_one(case) -> record`` (a dict).

    ``finished``: {key(case): record} of cases done before (a restart): their records are reused,
    not run again. ``on_record(record)`` is called on the running rank after each new case (e.g.
    ``pardem.io.records.RecordLog.append``, so a kill keeps every finished case). Returns on rank 0
    every record in the order of ``cases`` (None on the other ranks)."""
    finished = finished or {}
    mine = []
    for k, case in enumerate(cases):
        if owner(k, comm.size) != comm.rank:
            continue
        ident = key(case) if key is not None else None
        if ident is not None and ident in finished:
            mine.append((k, finished[ident]))
            continue
        record = run_one(case)
        if on_record is not None:
            on_record(record)
        mine.append((k, record))
    comm.wait_for_all()        # a rank done early sleeps here, not in the gather's busy poll
    parts = comm.gather(mine)
    if not comm.is_root:
        return None
    return [rec for _, rec in sorted((kr for part in parts for kr in part), key=lambda kr: kr[0])]
