"""The names liemef's options take, in one place that loads without JAX or numpy.

The modules that define what a name means take their list from here (:data:`liemef.connections.CARTAN_SCHOUTEN`,
:data:`liemef.filters.ORDERS`, :data:`liemef.codegen.BACKENDS`, :data:`liemef.integrators.INTEGRATORS`), and so
does the command line, whose choices and help must be known before JAX is imported.
"""

CONNECTIONS = ("minus", "zero", "plus")
"""The named members of the Cartan-Schouten family, in the order of their coefficient c = 0, 1/2, 1."""
ORDERS = ("second", "first")
"""The filter orders: ``"second"`` (Theorem 4.1, the papers' filter) and ``"first"`` (the left-invariant EKF)."""
C_BACKENDS = ("auto", "scalar", "array")
"""The C translators of :func:`liemef.codegen.export_c`."""
INTEGRATORS = ("rkmk4", "rkmk2", "lie-euler")
"""The integrators by their own names, which :data:`liemef.integrators.INTEGRATORS` takes (adding aliases), and
``liemef run``, ``smooth`` and ``tune`` offer (``tests/test_integrators.py`` checks that each names one)."""
EXPORT_INTEGRATORS = ("rkmk4", "lie-euler")
"""The integrators ``liemef export-c`` offers."""
INTERPOLATIONS = ("hold", "linear")
"""How inputs and dense measurements vary inside a sample interval: held (zero-order hold, the papers') or
linear between the interval's two samples (first-order hold, so that RKMK4's inner stages see current data)."""
UPDATES = ("hold", "discrete")
"""How a sample-meaning measurement enters: ``"hold"`` (its information spread over the interval after its time
stamp, the papers' zero-order hold) or ``"discrete"`` (used at its own time: the hybrid minimum-energy filter's
update, :mod:`liemef.filters._update`)."""
ERROR_SIDES = ("auto", "left", "right")
"""The minimum-energy filter's error coordinates (``MinimumEnergyFilter(error=...)``): chosen from the sensors
(:func:`liemef.systems.natural_error`), the left error (Theorem 4.1's) or the right error."""
