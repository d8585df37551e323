"""Proposition 23 measured: the diameter of Θ_k with and without a persistently exciting input.

For each seed, two closed loops on the problem's scenario with the same disturbance sequence
(i.i.d. uniform on W, the support assumption of Proposition 23): the exact update (7) (or the
update given) without PE, and with the PE constraint of docs/explanation/paper.md §8 (``OnlineOptions(pe_window,
pe_level)``). diam Θ_k = sup_{θ1,θ2∈Θ_k} ‖θ1 − θ2‖ (vertex enumeration) is recorded per k and per
seed; the JSON holds every series, the median and quartiles over seeds, and the values at
checkpoints; the PNG plots the median with the min–max band over seeds on a log scale. Also
recorded: Assumption 20 (rank Ξ), the PE measure of Definition 21 (λ_min of Σ_window D_kᵀD_k) of the
realised regressors, and the realised λ_min of the stacked-input window Gram (Lemma 24's condition).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import ProblemSpec
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.excitation import assumption20, pe_measure, stacked_gram, theta_diameter
from amcp_drake.online.simulate import simulate

#: Steps at which the table of the command (and the JSON "checkpoints") reports the diameters.
CHECKPOINT_FRACTIONS = (0.0, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0)


def diameters(traj) -> np.ndarray:
    """diam Θ_k for every record of a trajectory."""
    return np.array([theta_diameter(r.H_theta, r.h_theta) for r in traj.records])


def checkpoints(steps: int) -> list[int]:
    """The steps k reported in tables: CHECKPOINT_FRACTIONS of ``steps``, rounded."""
    return sorted({int(round(f * steps)) for f in CHECKPOINT_FRACTIONS})


def _input_excitation(u: np.ndarray, n: int, window: int) -> float:
    """Median over the second half of the run of λ_min of the (n+1)-dimensional window Gram of the inputs."""
    ks = range(max(window + n - 1, len(u) // 2), len(u))
    vals = [np.linalg.eigvalsh(stacked_gram(u, k, n + 1, window))[0] for k in ks]
    return float(np.median(vals)) if vals else float("nan")


def run_pe_figure(spec: ProblemSpec, design: OfflineDesign, seeds: int = 5, steps: int = 500, update: str = "exact",
                  pe_window: int = 10, pe_level: float = 1.0, backend: str = "drake", progress=None) -> dict:
    """diam Θ_k over ``seeds`` runs (seeds 0..seeds−1), with and without PE; a JSON-able dict.

    ``progress``: optional callable(label, seed) called before each run."""
    pr, sc = spec.problem, spec.scenario
    holds, sv = assumption20(pr)
    out = {"problem": pr.name, "seeds": list(range(seeds)), "steps": steps, "update": update, "pe_window": pe_window,
           "pe_level": pe_level, "backend": backend, "x0": np.asarray(sc.x0).tolist(),
           "theta_star": np.asarray(sc.theta_star).tolist(), "disturbance": "uniform",
           "assumption20": {"holds": holds, "singular_values": sv.tolist()}, "checkpoints": checkpoints(steps),
           "runs": {}}
    for label, opts in (("no_pe", OnlineOptions(update=update)),
                        ("pe", OnlineOptions(update=update, pe_window=pe_window, pe_level=pe_level))):
        ctrl = AdaptiveMPC(pr, design, backend=backend, options=opts)
        diams, lam_d, lam_u, statuses, completed = [], [], [], {}, 0
        for s in range(seeds):
            if progress is not None:
                progress(label, s)
            traj = simulate(ctrl, sc.x0, sc.theta_star, steps, "uniform", seed=s)
            completed += traj.stop_reason == "completed"
            dk = diameters(traj)
            diams.append(np.pad(dk, (0, steps + 1 - len(dk)), constant_values=np.nan))
            D = np.array([pr.regressor(x, u) for x, u in zip(traj.x, traj.u)])
            lo, _ = pe_measure(D, pe_window)
            lam_d.append(float(np.median(lo[len(lo) // 2:])) if len(lo) else float("nan"))
            lam_u.append(_input_excitation(traj.u[:, 0], pr.n, pe_window) if pr.m == 1 else float("nan"))
            for r in traj.records:
                statuses[r.pe_status] = statuses.get(r.pe_status, 0) + 1
        diams = np.array(diams)
        q25, med, q75 = np.nanpercentile(diams, [25, 50, 75], axis=0)
        out["runs"][label] = {
            "completed": completed, "diameter_per_seed": diams.tolist(),
            "median_diameter": med.tolist(), "q25_diameter": q25.tolist(), "q75_diameter": q75.tolist(),
            "mean_diameter": np.nanmean(diams, axis=0).tolist(),
            "min_diameter": np.nanmin(diams, axis=0).tolist(), "max_diameter": np.nanmax(diams, axis=0).tolist(),
            "final_diameter_per_seed": diams[:, -1].tolist(),
            "regressor_pe_lambda_min_median_second_half_per_seed": lam_d,
            "input_gram_lambda_min_median_second_half_per_seed": lam_u,
            "pe_status_counts": statuses,
        }
    pe_final, no_final = np.array(out["runs"]["pe"]["final_diameter_per_seed"]), np.array(out["runs"]["no_pe"]["final_diameter_per_seed"])
    out["seeds_pe_smaller_at_end"] = int(np.sum(pe_final < no_final))
    return out


def write_pe_figure(result: dict, out_dir: str | Path) -> tuple[Path, Path]:
    """pe_diameter.json and pe_diameter.png in ``out_dir`` (both written atomically)."""
    import os
    import tempfile

    from amcp_drake.model.problem_io import write_json_atomic

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for label, name, colour in (("no_pe", "without PE", "tab:blue"),
                                ("pe", f"with PE (P = {result['pe_window']}, ρ = {result['pe_level']:g})", "tab:red")):
        run = result["runs"][label]
        k = np.arange(len(run["median_diameter"]))
        ax.plot(k, run["median_diameter"], color=colour, label=f"{name}, median")
        ax.fill_between(k, run["min_diameter"], run["max_diameter"], color=colour, alpha=0.2, linewidth=0)
    ax.set_yscale("log")
    ax.set_xlabel("step k")
    ax.set_ylabel("diam Θ_k")
    ax.set_title(f"{result['problem']}: update {result['update']}, {len(result['seeds'])} seeds (band: min–max)")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    png = out_dir / "pe_diameter.png"
    fd, tmp = tempfile.mkstemp(dir=out_dir, prefix=".pe_diameter.", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png")
        os.chmod(tmp, 0o644)
        os.replace(tmp, png)
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.unlink(tmp)
    js = write_json_atomic(result, out_dir / "pe_diameter.json")
    return js, png
