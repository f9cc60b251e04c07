"""Physics kernels: pure functions over arrays (Numba), free of MPI and files."""
