import liemef  # noqa: F401  (enables float64 before any test creates an array)
