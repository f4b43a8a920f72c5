"""Analyse: what the runs left, read and never started. Records packed into the repository (`records`), where
a recipe's seeds are (`rundirs`) and where each stands (`seed_status`), summaries and figures (`summaries`,
`kinds`, `plot_figures`, `predictions`), the evaluation and branch designs' results (`evaluation_results`,
`branch_results`), the sweep's (`sweep_results`) and the follow-ups' (`followup_results`), every kind's
verdict (`verdicts`) and simulated power (`power`), time to learning (`takeoff`, `takeoff_power`), run times
(`run_times`) and which CPU kinds agree (`cpu_kinds`). Imports nothing of launch."""
