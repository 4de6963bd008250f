"""Run ukfm's own attitude benchmark code on seeded runs: the figures behind
``liemef.studies.experiments.ukfm_attitude.PER_SEED`` (docs/comparisons.md, "ukfm's attitude benchmark").

ukfm (Brossard, Barrau & Bonnabel; BSD-3) is not a dependency of liemef: give the path of a checkout's ``python``
folder. For each seed k this calls ``np.random.seed(k)`` and then does what one Monte Carlo run of ukfm's
``python/benchmarks/attitude.py`` does, with ukfm's own model and filters: ``simu_f``, ``simu_h``, the drawn
initial estimate, the left and right UKF-M and the EKF from the true start, ``errors`` and ``nees``. It prints one
JSON line per seed: each filter's per-axis rms (deg, all n) and NEES (ukfm's definition), the drawn initial error
(deg) and the wall time; ``--save DIR`` also writes the run's arrays (truth, gyro, measurements, estimates and
covariances) as ``ukfm_attitude_seed{k}.npz``. ukfm's model module imports matplotlib.

    python tools/ukfm_attitude_runs.py --ukfm PATH/TO/ukfm/python --seeds 0-19 [--save DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def seeds_of(text: str) -> list[int]:
    """``"0-19"`` or ``"0,3,7"`` as a list of seeds."""
    if "-" in text:
        lo, hi = (int(v) for v in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(v) for v in text.split(",")]


def run(seed: int, save: Path | None = None) -> dict:
    """One run of ukfm's benchmark loop body after ``np.random.seed(seed)`` (ukfm importable)."""
    import numpy as np
    from scipy.linalg import block_diag
    from ukfm import ATTITUDE, EKF, SO3, UKF

    model = ATTITUDE(100, 100)
    imu_std = np.array([5 / 180 * np.pi, 0.4, 0.3])
    Q = imu_std[0] ** 2 * np.eye(3)
    R = block_diag(imu_std[1] ** 2 * np.eye(3), imu_std[2] ** 2 * np.eye(3))
    P0 = (10 / 180 * np.pi) ** 2 * np.eye(3)
    alpha = np.array([1e-3, 1e-3, 1e-3])
    np.random.seed(seed)
    t0 = time.time()
    states, omegas = model.simu_f(imu_std)
    ys = model.simu_h(states, imu_std)
    state0 = model.STATE(Rot=states[0].Rot.dot(SO3.exp(10 / 180 * np.pi * np.random.randn(3))))
    filters = {
        "left": UKF(state0=states[0], P0=P0, f=model.f, h=model.h, Q=Q, R=R, phi=model.phi, phi_inv=model.phi_inv,
                    alpha=alpha),
        "right": UKF(state0=states[0], P0=P0, f=model.f, h=model.h, Q=Q, R=R, phi=model.right_phi,
                     phi_inv=model.right_phi_inv, alpha=alpha),
        "ekf": EKF(model=model, state0=states[0], P0=P0, Q=Q, R=R, FG_ana=model.ekf_FG_ana, H_ana=model.ekf_H_ana,
                   phi=model.right_phi),
    }
    estimates = {k: [state0] for k in filters}
    Ps = {k: np.zeros((model.N, 3, 3)) for k in filters}
    Ps["left"][0] = state0.Rot.dot(P0).dot(state0.Rot.T)
    Ps["right"][0] = Ps["ekf"][0] = P0
    for n in range(1, model.N):
        for k, f in filters.items():
            f.propagation(omegas[n - 1], model.dt)
            f.update(ys[n])
            estimates[k].append(f.state)
            Ps[k][n] = f.P
    Rots, _ = model.get_states(states, model.N)
    out, arrays = {"seed": seed}, {"Rots": Rots, "gyro": np.array([o.gyro for o in omegas]), "ys": ys,
                                   "Rot0_hat": state0.Rot}
    for k in filters:
        hat, _ = model.get_states(estimates[k], model.N)
        err = model.errors(Rots, hat)
        nees = model.nees(err, Ps[k], hat, "LEFT" if k == "left" else "RIGHT")
        out[k] = {"rms_deg": float(np.degrees(np.sqrt(np.mean(err**2)))), "nees": float(np.mean(nees))}
        arrays[f"{k}_Rots"], arrays[f"{k}_P"] = hat, Ps[k]
    out["initial_error_deg"] = float(np.degrees(np.linalg.norm(SO3.log(Rots[0].T.dot(state0.Rot)))))
    out["wall_s"] = time.time() - t0
    if save is not None:
        np.savez_compressed(save / f"ukfm_attitude_seed{seed}.npz", **arrays)
    return out


def main(argv: list[str] | None = None) -> None:
    """The command line (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ukfm", required=True, type=Path, help="the python folder of a ukfm checkout")
    p.add_argument("--seeds", default="0-19", help="seeds, as 0-19 or 0,3,7")
    p.add_argument("--save", type=Path, help="a folder for the runs' arrays")
    args = p.parse_args(argv)
    if not (args.ukfm / "ukfm" / "__init__.py").is_file():
        p.error(f"--ukfm: expected the python folder of a ukfm checkout (holding ukfm/__init__.py), got {args.ukfm}")
    import matplotlib

    matplotlib.use("Agg")
    sys.path.insert(0, str(args.ukfm))
    for seed in seeds_of(args.seeds):
        print(json.dumps(run(seed, args.save)), flush=True)


if __name__ == "__main__":
    main()
