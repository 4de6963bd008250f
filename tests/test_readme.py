"""The README's Python examples run as written (documentation that cannot rot)."""

import pathlib
import re

import numpy as np

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_readme_examples_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 2
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
    traj, truth = namespace["traj"], namespace["truth"]
    assert bool(traj.ok) and traj.coords().shape == (5001, 6)
    # the example is a working filter: after 5 s the position error is well below the 0.5 m antenna noise
    err = namespace["liemef"].metrics.state_error(truth.g, traj.g_hat)
    assert float(abs(err[-1, 1:3]).max()) < 0.1
    assert namespace["terms"].E.shape == (6, 6)
    assert namespace["flt"].system.group.__name__ == "SO2xR1"
    # the real-logs example: sparse GPS corrects a 0.5 rad initial heading error
    loc = namespace["loc_traj"]
    assert loc.status.ok and int(loc.status.substeps_total) > 3999  # the GPS intervals were sub-stepped
    theta, x, y = (float(v) for v in loc.coords()[-1])
    true_theta = 0.157 * 39.99
    assert abs((theta - true_theta + 3.14159) % 6.28318 - 3.14159) < 0.1
    assert abs(x - 5 * np.sin(true_theta)) < 1.0 and abs(y - (5 - 5 * np.cos(true_theta))) < 1.0
