"""The README's Python examples run as written (documentation that cannot rot)."""

import pathlib
import re

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_readme_examples_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 2
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
    traj, truth = namespace["traj"], namespace["truth"]
    assert bool(traj.finite) and traj.coords().shape == (5001, 6)
    # the example is a working filter: after 5 s the position error is well below the 0.5 m antenna noise
    err = namespace["liemef"].metrics.state_error(truth.g, traj.g_hat)
    assert float(abs(err[-1, 1:3]).max()) < 0.1
    assert namespace["terms"].E.shape == (6, 6)
    assert namespace["flt"].system.group.__name__ == "SO2xR1"
