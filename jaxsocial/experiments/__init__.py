"""The paper's experiments: one command, `python -m jaxsocial.experiments VERB NAME`, for recipes, for
pre-registered designs of every kind (NAME's kind comes from its design file, `catalogue`) and for the
exploratory sweep's settings (`sweeps/NAME.json`).

    python -m jaxsocial.experiments list                              # recipes, designs by kind, scales
    python -m jaxsocial.experiments run h1 --scale cpu --seeds 3      # train what is missing, resume the rest
    python -m jaxsocial.experiments figure h1 --scale cpu --seeds 3   # into runs/experiments/figures/
    python -m jaxsocial.experiments record h1 --scale cpu --seeds 3 --commands-log LOG --device D --jax V
    python -m jaxsocial.experiments status pred8 --scale laptop8      # where each seed stands, blind
    python -m jaxsocial.experiments power h1_prereg                   # a pre-registered design and its power
    python -m jaxsocial.experiments run transfer8                     # an evaluation design: plays records
    python -m jaxsocial.experiments run mixing --cores 0 1            # a branch design: trains on from them
    python -m jaxsocial.experiments sweep list                        # the exploratory sweep of settings
    python -m jaxsocial.experiments run mb8k8_rec --seeds 0 1         # a sweep setting's seeds, a core each
    python -m jaxsocial.experiments followup run h1_laptop            # follow-ups of a design's learned seeds

The modules form three layers, each a folder, in the order the work flows (`tests/test_experiment_layers.py`
keeps the arrows so): `plan/` imports neither of the others; `launch/` uses plan and analyse's readers;
`analyse/` never imports launch. Each folder's `__init__` names its modules.

The commands on top use all three: `__main__` (one command, every verb), `kind_commands` (the verbs of the
evaluation and branch designs, whose parts are `plan.<kind>_design`, `launch.evaluation_play` or
`launch.branch_runs`, and `analyse.<kind>_results`), `sweep` (screens settings: `plan.sweep_settings`,
`launch.sweep_runs`, `analyse.sweep_results`) and `followup` (branches, transfers and probes a design's
learners that learned: `plan.followup_plan`, `launch.followup_runs`, `analyse.followup_results`). They work on
a checkout of the repository, run from its root (`paths.require_checkout`)."""
