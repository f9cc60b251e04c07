"""Where the ranks of a job run: how many share this rank's node (its memory)."""


def ranks_on_node(comm):
    """Collective: the number of ranks of ``comm`` (a ``Communicator``) on this rank's node, those
    that can share memory (``MPI_Comm_split_type(MPI_COMM_TYPE_SHARED)``); 1 on one rank."""
    if comm is None or comm.size == 1:
        return 1
    from mpi4py import MPI
    node = comm.comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        return node.Get_size()
    finally:
        node.Free()
