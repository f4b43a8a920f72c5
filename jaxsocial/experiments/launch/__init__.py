"""Launch: what starts processes. The recipe runner (`runner`), single-core pinned processes on this machine
(`pinned`) or one-CPU jobs on a Slurm cluster (`slurm`, chosen in one place: `slurm.chosen`), an evaluation
design's evaluations (`evaluation_play`), a branch design's runs (`branch_runs`), GPU blocks resumed across
machines (`inflight`) and re-training a record to compare (`verify`). Uses plan and analyse's readers."""
