"""The studies: what liemef computes with its filters, on simulated and on real data.

* :mod:`liemef.studies.experiments`: the papers' experiments (frozen configs plus ``run``), Monte Carlo over
  seeded trials and the reproductions;
* :mod:`liemef.studies.compare`: the minimum-energy filter against the baselines, on the same trials;
* :mod:`liemef.studies.campaign`: Monte Carlo campaigns over a grid of settings, resumable and distributed;
* :mod:`liemef.studies.optimum`: the exact minimum-energy (batch MAP) estimate, by GTSAM;
* :mod:`liemef.studies.datasets`: the real recordings (BROAD, Wifibot) as logs with their truth.
"""

from . import registry


def load(kind: str, name: str):
    """The full study ``name`` of ``kind`` declared in :mod:`liemef.studies.registry` (a ValueError listing the
    names otherwise): an :class:`~liemef.studies.experiments.Experiment` for ``"experiment"``, a
    :class:`~liemef.studies.compare.Study` for ``"comparison"``. Imports the module that holds it (hence JAX)."""
    registry.get(kind, name)
    if kind == "experiment":
        from .experiments import EXPERIMENTS

        return EXPERIMENTS[name]
    from .compare import STUDIES

    return STUDIES[name]
