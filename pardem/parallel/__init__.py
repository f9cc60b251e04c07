"""The parallel layer: the only place that talks MPI."""
