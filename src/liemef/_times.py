"""How messages and figures say a time: relative to the start of its log, for logs whose time stamps are epoch
seconds (a ROS bag's), which printed with six significant digits would read 1.7e+09 at every sample. Loads
without JAX or numpy."""


def seconds(t: float) -> str:
    """A time in seconds with all its digits down to the microsecond: ``1700000012.3``, not ``1.7e+09``."""
    return f"{t:.6f}".rstrip("0").rstrip(".")


def time_said(t: float, t0: float = 0.0) -> str:
    """A time as the messages say it, relative to the start ``t0`` of its log: ``"t = 12.3 s"`` for a log that
    starts at 0, else ``"t = t0 + 12.3 s (1700000012.3 s)"``."""
    if t0 == 0.0:
        return f"t = {t:.6g} s"
    return f"t = t0 + {t - t0:.6g} s ({seconds(t)} s)"
