"""Proposition 23 measured: the diameter of Θ_k with and without a persistently exciting input.

For each seed, two closed loops on the problem's scenario with the same disturbance sequence
(i.i.d. uniform on W, the support assumption of Proposition 23): the exact update (7) (or the
update given) without PE, and with the PE constraint of spec §8 (``OnlineOptions(pe_window,
pe_level)``). diam Θ_k = sup_{θ1,θ2∈Θ_k} ‖θ1 − θ2‖ (vertex enumeration) is recorded per k; the
mean over seeds is written as JSON and plotted as PNG. Also recorded: Assumption 20 (rank Ξ) and
the PE measure of Definition 21 (λ_min of Σ_window D_kᵀD_k) of the realised regressors.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .controller import AdaptiveMPC, OnlineOptions
from .design import OfflineDesign
from .excitation import assumption20, pe_measure, theta_diameter
from .problem import ProblemSpec
from .simulate import simulate


def diameters(traj) -> np.ndarray:
    """diam Θ_k for every record of a trajectory."""
    return np.array([theta_diameter(r.H_theta, r.h_theta) for r in traj.records])


def run_pe_figure(spec: ProblemSpec, design: OfflineDesign, seeds: int = 5, steps: int = 150, update: str = "exact",
                  pe_window: int = 10, pe_level: float = 0.2, backend: str = "drake") -> dict:
    """Mean diam Θ_k over ``seeds`` runs, with and without PE; returns a JSON-able dict."""
    pr, sc = spec.problem, spec.scenario
    holds, sv = assumption20(pr)
    out = {"problem": pr.name, "seeds": list(range(seeds)), "steps": steps, "update": update, "pe_window": pe_window,
           "pe_level": pe_level, "backend": backend, "assumption20": {"holds": holds, "singular_values": sv.tolist()},
           "runs": {}}
    for label, opts in (("no_pe", OnlineOptions(update=update)),
                        ("pe", OnlineOptions(update=update, pe_window=pe_window, pe_level=pe_level))):
        ctrl = AdaptiveMPC(pr, design, backend=backend, options=opts)
        diams, lam_min, statuses, completed = [], [], {}, 0
        for s in range(seeds):
            traj = simulate(ctrl, sc.x0, sc.theta_star, steps, "uniform", seed=s)
            completed += traj.stop_reason == "completed"
            dk = diameters(traj)
            diams.append(np.pad(dk, (0, steps + 1 - len(dk)), constant_values=np.nan))
            D = np.array([pr.regressor(x, u) for x, u in zip(traj.x, traj.u)])
            lo, _ = pe_measure(D, pe_window)
            lam_min.append(float(np.min(lo[len(lo) // 2:])) if len(lo) else float("nan"))
            for r in traj.records:
                statuses[r.pe_status] = statuses.get(r.pe_status, 0) + 1
        diams = np.array(diams)
        out["runs"][label] = {
            "completed": completed, "mean_diameter": np.nanmean(diams, axis=0).tolist(),
            "final_diameter_per_seed": diams[:, -1].tolist(),
            "pe_lambda_min_second_half_per_seed": lam_min, "pe_status_counts": statuses,
        }
    return out


def write_pe_figure(result: dict, out_dir: str | Path) -> tuple[Path, Path]:
    """pe_diameter.json and pe_diameter.png in ``out_dir``."""
    from .problem_io import write_json_atomic

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    js = write_json_atomic(result, out_dir / "pe_diameter.json")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for label, name in (("no_pe", "without PE"), ("pe", f"with PE (P={result['pe_window']}, ρ={result['pe_level']})")):
        d = result["runs"][label]["mean_diameter"]
        ax.plot(range(len(d)), d, label=name)
    ax.set_xlabel("step k")
    ax.set_ylabel("mean diam Θ_k")
    ax.set_title(f"{result['problem']}: update {result['update']}, {len(result['seeds'])} seeds")
    ax.grid(alpha=0.3)
    ax.legend()
    png = out_dir / "pe_diameter.png"
    fig.savefig(png, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return js, png
