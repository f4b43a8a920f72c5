"""The paper's experiments: one command, `python -m jaxsocial.experiments VERB NAME`, for recipes and for
pre-registered designs of every kind (NAME's kind comes from its design file, `catalogue`).

    python -m jaxsocial.experiments list                              # recipes, designs by kind, scales
    python -m jaxsocial.experiments run h1 --scale cpu --seeds 3      # train what is missing, resume the rest
    python -m jaxsocial.experiments figure h1 --scale cpu --seeds 3   # into runs/experiments/figures/
    python -m jaxsocial.experiments record h1 --scale cpu --seeds 3 --commands-log LOG --device D --jax V
    python -m jaxsocial.experiments power h1_prereg                   # a pre-registered design and its power
    python -m jaxsocial.experiments run transfer8                     # an evaluation design: plays records
    python -m jaxsocial.experiments run mixing --cores 0 1            # a branch design: trains on from them
    python -m jaxsocial.experiments sweep list                        # the exploratory sweep of settings
    python -m jaxsocial.experiments followup run h1_laptop            # follow-ups of a design's learned seeds

The modules form three layers, in the order the work flows (`tests/test_experiment_layers.py` keeps the
arrows so):

* plan, which imports neither of the others: `conditions` (what each changes, its label), `recipes`
  (conditions x scales), `catalogue` (the design files of every kind, `designs/*.json`, and each one's kind),
  `prereg` (training designs), `paths` (where everything is read and written), `xla_flags` (the runs'
  $XLA_FLAGS, checked), `commits` (which commit);
* launch: `runner` (trains and evaluates a recipe), `pinned` (one single-core process per seed), `inflight`
  (GPU blocks resumed across machines), `verify` (re-trains a record and compares);
* analyse, which never imports launch: `records` (run directories packed into the repository's records),
  `summaries` (summaries and figures; `takeoff`: time to learning, `stats`: the tests over seeds),
  `plot_figures`, `kinds` (per kind of recipe: how it is evaluated, summarised and drawn), `rundirs`,
  `predictions` (a learner's predicted next frames), `takeoff_power`.

The commands on top use all three: `__main__`, `sweep` (screens settings), `followup` (branches, transfers
and probes a design's learners that learned), `evaluation_design` (designs that only evaluate committed
records) and `branch_design` (designs that train on from committed records' policies), each with its plan,
launch and analysis in that order. They work on a checkout of the repository, run from its root
(`paths.require_checkout`).
"""
