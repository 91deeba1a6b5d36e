"""Shared helpers with no knowledge of scenes or engines: vectors, rigid fits, JSON, MPI, progress."""
