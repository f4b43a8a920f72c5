"""Launch: what starts processes. The recipe runner (`runner`) and its records packed (`recipe_records`),
single-core pinned processes on this machine (`pinned`) or one-CPU jobs on a Slurm cluster (`slurm`, chosen in
one place: `slurm.chosen`), policies played zero-shot and an evaluation design's evaluations
(`evaluation_play`), a branch design's runs (`branch_runs`), the sweep's seeds (`sweep_runs`), a design's
follow-ups (`followup_runs`), GPU blocks resumed across machines (`inflight`) and re-training a record to
compare (`verify`). Uses plan and analyse's readers."""
