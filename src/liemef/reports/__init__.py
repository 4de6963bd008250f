"""The reports: what a study writes, apart from what it computes.

* :mod:`liemef.reports.io`: logs in (CSV, NPZ) and results out (JSON, NPZ, CSV), each file written whole or
  not at all;
* :mod:`liemef.reports.rosbag`: ROS 1 and ROS 2 bags in, by a mapping from topics to the system's columns;
* :mod:`liemef.reports.plots`: the state figures of a result folder, and saving a figure;
* :mod:`liemef.reports.figures`: the studies' own figures (comparisons, paper figures), from saved arrays;
* :mod:`liemef.reports.montecarlo`: a Monte Carlo result's tables (text, Markdown, CSV) and its npz + json files
  (schema ``liemef.montecarlo/1``), written and read back;
* :mod:`liemef.reports.chaplygin`: the Chaplygin reproduction's Tables 1-2 against the paper and Figs. 3-6;
* :mod:`liemef.reports.progress`: the progress line of Monte Carlos, reproductions and campaigns;
* :mod:`liemef.reports.outputs`: output folders written whole, with a manifest.

Only this layer imports matplotlib (``tests/test_layers.py``).
"""
