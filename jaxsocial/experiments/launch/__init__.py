"""Launch: what starts processes. The recipe runner (`runner`), single-core pinned processes (`pinned`), GPU
blocks resumed across machines (`inflight`) and re-training a record to compare (`verify`). Uses plan and
analyse's readers."""
