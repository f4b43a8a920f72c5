"""The paper's experiments, one command per figure.

    python -m jaxsocial.experiments list
    python -m jaxsocial.experiments run h1 --scale cpu --seeds 3      # train what is missing, resume the rest
    python -m jaxsocial.experiments figure h1 --scale cpu --seeds 3   # into runs/experiments/figures/
    python -m jaxsocial.experiments record h1 --scale cpu --seeds 3 --commands-log LOG --device D --jax V
    python -m jaxsocial.experiments power h1_prereg                   # a pre-registered design and its power
    python -m jaxsocial.experiments.sweep list                        # the exploratory sweep of settings
    python -m jaxsocial.experiments.followup run h1_laptop            # follow-ups of a design's learned seeds
    python -m jaxsocial.experiments.evaluation_design run transfer    # a pre-registered design over records
    python -m jaxsocial.experiments.branch_design run mixing --cores 0 1   # one that trains on from records

`recipes` names the conditions and scales, `runner` trains and evaluates them, `summaries` summarises and
draws them (`takeoff`: time to learning; `stats`: the tests and estimates over seeds), `records` packs run
directories into the repository's records, `prereg` holds pre-registered designs (`designs/*.json`),
`evaluation_design` those that only evaluate committed records (`evaluation_designs/*.json`), `branch_design`
those that train on from committed records' policies (`branch_designs/*.json`),
`predictions` draws a learner's predicted next frames, `sweep` screens settings, `followup` branches,
transfers and probes a design's learners that learned, `pinned` runs one single-core process per seed; `kinds`
says, per kind of recipe, how it is evaluated after training, summarised and drawn; `paths` names where
everything is read and written. They work on a checkout of the repository, run from its root
(`paths.require_checkout`).
"""
