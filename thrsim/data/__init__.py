"""Ground-truth case files (HDF5), sweeps and executors, α labels, splits."""
