"""numba plumbing (private): threads and their twins, the one function cloner,
per-thread reductions, the compilation cache."""
