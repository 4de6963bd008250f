import liemef._config  # noqa: F401  (switches JAX to float64 before any test creates an array)
