"""The studies: what liemef computes with its filters, on simulated and on real data.

* :mod:`liemef.studies.experiments`: the papers' experiments (frozen configs plus ``run``), Monte Carlo over
  seeded trials and the reproductions;
* :mod:`liemef.studies.compare`: the minimum-energy filter against the baselines, on the same trials;
* :mod:`liemef.studies.campaign`: Monte Carlo campaigns over a grid of settings, resumable and distributed;
* :mod:`liemef.studies.optimum`: the exact minimum-energy (batch MAP) estimate, by GTSAM;
* :mod:`liemef.studies.datasets`: the real recordings (BROAD, Wifibot) as logs with their truth.
"""
