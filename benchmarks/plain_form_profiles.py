"""How each tube QP (20) of the large shipped examples is answered under the Clarabel settings profiles of
properties/amcp_properties/clarabel_settings.py (Drake backend, both formulations): one letter per
closed-loop step, ``1`` = the first Clarabel try "Solved", ``r`` = answered by the form's own re-solves
(refinement, retry ladder), ``F`` = the step answered by the other formulation (fallback), ``-`` = not
solved. Prints a markdown table (docs/results.md, "The Drake plain form under other Clarabel settings").

    PYTHONPATH=.:reference:properties python benchmarks/plain_form_profiles.py
"""

from __future__ import annotations

from amcp_drake.model.examples import EXAMPLES
from amcp_drake.offline.design import design
from amcp_drake.online import answers
from amcp_drake.online.replay import run_scenario
from amcp_properties.clarabel_settings import CLARABEL_PROFILES, LARGE_EXAMPLE_STEPS, MEASURED_ONLY_PROFILES


def code(record) -> str:
    entry = answers.of(record, "tube_qp")
    if entry is None or entry["outcome"] == "not_solved":
        return "-"
    if entry["outcome"] == "fallback":
        return "F"
    return "1" if entry["outcome"] == "first" and not record.qp_detail.split(";")[0].startswith(
        ("re-solved", "Clarabel retry", "every row")) and "tries not solved" not in record.qp_detail else "r"


def main() -> None:
    profiles = {"defaults": {}, **CLARABEL_PROFILES, **MEASURED_ONLY_PROFILES}
    print("| example, form | " + " | ".join(profiles) + " |")
    print("|---|" + "---|" * len(profiles))
    for name, steps in LARGE_EXAMPLE_STEPS.items():
        spec = EXAMPLES[name]()
        offline = design(spec.problem, spec.design, backend="drake")
        for form in ("plain", "vertex"):
            cells = []
            for options in profiles.values():
                traj = run_scenario(spec, "drake", offline=offline, steps=steps, formulation=form,
                                    backend_options={"solver_options": dict(options)})
                cells.append("".join(code(r) for r in traj.records))
            print(f"| {name}, {form} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
