"""A user's system from a Python file (`liemef run --system-file`) and the log schema of a system."""

import numpy as np
import pytest

from liemef.systems import PlanarRigidBody, planar_localization
from liemef.systems._file import format_schema, load_system_file, log_schema

USER_FILE = '''
import numpy as np
from liemef.groups import SE2
from liemef.systems import Noise, Sensor, SensorSystem

def dynamics(g, u, t):
    import jax.numpy as jnp
    return jnp.stack([u[1], u[0], 0.0 * u[0]])

def gps(g, t):
    return g.cos_sin_xy[2:4]

system = SensorSystem(SE2, dynamics, [Sensor("gps", gps, Noise.sample(0.5), ("x", "y"), ("m", "m"))],
                      Noise.density([0.01, 0.02, 0.02]), inputs=("v", "omega"), input_units=("m/s", "rad/s"))
K0 = [0.1, 1.0, 1.0]
x0 = [0.0, 1.0, 2.0]
'''


def test_a_system_file_defines_the_system_and_optional_initial_values(tmp_path):
    p = tmp_path / "my_system.py"
    p.write_text(USER_FILE)
    user = load_system_file(p)
    assert user.system.output_names == ("gps_x", "gps_y") and user.system.input_names == ("v", "omega")
    np.testing.assert_array_equal(user.K0, np.diag([0.1, 1.0, 1.0]))
    np.testing.assert_array_equal(user.x0, [0.0, 1.0, 2.0])
    assert user.initial_guess is None


@pytest.mark.parametrize(("text", "match"), [
    (None, "not found"),
    ("x = (", "running .* failed: SyntaxError"),
    ("raise RuntimeError('no sensor here')", "failed: RuntimeError: no sensor here"),
    ("system = 3", "expected .* to define `system`, a liemef system .* got int"),
    (USER_FILE + "\nK0 = [1.0, 2.0]\n", r"K0: expected shape \(3, 3\) or \(3,\), got \(2,\)"),
    (USER_FILE + "\nx0 = [1.0]\n", r"x0: expected 3 coordinates, got shape \(1,\)"),
])
def test_bad_system_files_name_the_option_and_the_problem(tmp_path, text, match):
    p = tmp_path / "bad.py"
    if text is not None:
        p.write_text(text)
    with pytest.raises(ValueError, match="--system-file: .*" + match):
        load_system_file(p)


def test_schema_lists_columns_with_units_and_noise_meaning():
    rows = log_schema(planar_localization())
    assert [r["column"] for r in rows] == ["t", "v_x", "v_y", "omega", "gps_x", "gps_y"]
    assert rows[4] == {"column": "gps_x", "unit": "m", "role": "sensor gps", "noise": "std 1 m per sample"}
    text = format_schema(PlanarRigidBody())
    assert "CSV header: t,u1,u2,x1,y1,x2,y2,omega,vx,vy" in text
