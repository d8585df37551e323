"""The ``amcp`` command line. Subcommands live in their own modules and are imported only when
invoked, so ``amcp --help`` never imports Drake or cvxpy.

Exit codes (design.md): 0 all claims hold / backends agree; 1 a claim failed / backends disagree;
2 bad input (a ProblemError, a missing file, a bad option).
"""

from __future__ import annotations

import importlib
import importlib.util

import click

#: subcommand -> (module, attribute, one-line help)
COMMANDS = {
    "design": ("amcp_drake.cli.design", "design_cmd", "Offline design (K, P, X0, Xf, mu) and its independent checks."),
    "run": ("amcp_drake.cli.run", "run_cmd", "Closed-loop run of a problem; prints the per-step table."),
    "certify": ("amcp_drake.cli.certify", "certify_cmd", "Certificate report: run, then check every claim independently."),
    "compare": ("amcp_drake.cli.compare", "compare_cmd", "Run the Drake and cvxpy backends side by side, step by step."),
    "verify": ("amcp_drake.cli.verify", "verify_cmd", "Run the hypothesis property suite (and mutants)."),
    "campaign": ("amcp_drake.cli.campaign", "campaign_cmd", "Verification campaign of random problems on Dask, stored in SQLite."),
    "baseline": ("amcp_drake.cli.baseline", "baseline_cmd", "Adaptive vs robust baseline: cost, tube size, feasible region."),
    "pe-figure": ("amcp_drake.cli.pe_figure", "pe_figure_cmd", "Proposition 23: diameter of Theta_k with and without PE (PNG + JSON)."),
    "coverage": ("amcp_drake.cli.coverage", "coverage_cmd",
                 "Feasible region of the QP (20) on a grid of x0, robust and after adaptation (QP + LP)."),
    "bench": ("amcp_drake.cli.bench", "bench_cmd", "Performance benchmarks (medians, ratios)."),
    "solvers": ("amcp_drake.cli.solvers", "solvers_cmd", "Solver conformance matrix on the corpus of this scheme's problems."),
}


class LazyGroup(click.Group):
    """A click group whose commands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return [name for name, (module, _, _) in COMMANDS.items() if importlib.util.find_spec(module) is not None]

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module_name, attr, _ = COMMANDS[name]
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError:
            return None
        return getattr(module, attr)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][2]) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="amcp-drake")
def main() -> None:
    """Verification suite for the adaptive robust MPC of Lorenzen, Cannon & Allgöwer (2019)."""
    from amcp_drake.backends.drake_log import drop_drake_info

    drop_drake_info()  # Drake's INFO lines off stderr; what they say is in the records


if __name__ == "__main__":  # pragma: no cover
    main()
