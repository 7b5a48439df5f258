"""Process-level compute settings shared by the numeric packages: numba compilation (`jit`) and
thread limits for work made of many small steps (`threads`)."""
