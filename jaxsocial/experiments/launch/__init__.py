"""Launch: what starts processes. The recipe runner (`runner`), single-core pinned processes (`pinned`), an
evaluation design's evaluations (`evaluation_play`), a branch design's runs (`branch_runs`), GPU blocks
resumed across machines (`inflight`) and re-training a record to compare (`verify`). Uses plan and
analyse's readers."""
