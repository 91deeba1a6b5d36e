"""Run directories: a run, checkpoints and --resume, sweeps and batches over MPI ranks."""
