"""The nonlinear worked example from the command line: an inverted pendulum as a discrete Drake
``MultibodyPlant``, its linearised model and W (amcp_drake/systems/pendulum.py), the closed loop in Drake's
Simulator, certified as a measured run.

    python examples/pendulum_in_drake.py [STEPS] [W_SCALE] [stop|reset]

STEPS (default 25) periods of 0.05 s; W_SCALE (default 1) scales the W that covers the linearisation error
(W_SCALE = 0.001 makes the data contradict the model); ``reset`` continues after such a step from Θ_k = Θ.
Prints the run and the certificate's verdict and consistency claim. Exit 0 when every applicable claim
holds, 1 otherwise, 2 on bad arguments. The tests run this file (tests/test_pendulum.py).
"""

from __future__ import annotations

import sys

import numpy as np

from amcp_drake.certificate.certify import certify
from amcp_drake.model.errors import ProblemError
from amcp_drake.systems.pendulum import run_pendulum, summary


def main(argv: list[str]) -> int:
    try:
        steps = int(argv[0]) if argv else 25
        w_scale = float(argv[1]) if len(argv) > 1 else 1.0
        run = run_pendulum(steps, w_scale=w_scale, on_inconsistent=argv[2] if len(argv) > 2 else "stop")
    except ValueError as exc:
        print(f"error: STEPS an integer, W_SCALE a number: {exc}", file=sys.stderr)
        return 2
    except ProblemError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cert = certify(run.trajectory)
    info = summary(run, cert)
    consistency = info["claims"]["data_consistency"]
    print(f"pendulum: {info['steps']} steps, {info['stop_reason']}; W half-widths "
          f"{np.round(info['W_half_widths'], 5).tolist()} (1.5 x the error sampled at {info['error_points']} points)")
    if info["theta_resets"]:
        print(f"Θ_k reset to Θ at steps {info['theta_resets']}")
    print(f"certificate: {cert.verdict} {info['counts']}; data_consistency {consistency['status']}, "
          f"margin {consistency['margin']:.4g} at step {consistency['worst_step']}")
    return 0 if cert.passed else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
