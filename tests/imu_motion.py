"""The synthetic IMU motion the IMU models' tests share: a body turning at about 1 rad/s."""

import numpy as np
from scipy.spatial.transform import Rotation


def turning(rate: float, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``ts`` (N,), the body rate ``w`` (N, 3) in rad/s and the rotations body -> world ``R`` (N, 3, 3), integrated
    exactly over each sample interval from ``R[0]`` = exp((0.2, -0.1, 0.5))."""
    ts = np.arange(N) / rate
    w = np.stack([0.8 * np.sin(0.5 * ts), 0.6 * np.cos(0.3 * ts + 1.0), 0.7 * np.sin(0.2 * ts + 2.0)], axis=1)
    R = np.empty((N, 3, 3))
    R[0] = Rotation.from_rotvec([0.2, -0.1, 0.5]).as_matrix()
    for k in range(N - 1):
        R[k + 1] = R[k] @ Rotation.from_rotvec(w[k] / rate).as_matrix()
    return ts, w, R
