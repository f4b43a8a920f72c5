"""Plan: what an experiment is before anything runs. The recipes (`recipes`: conditions x scales;
`conditions`: what each changes), the design files of every kind and their one loader (`catalogue`, whose
`Design` each kind extends): training designs (`prereg`), evaluation designs (`evaluation_design`) and
branch designs (`branch_design`); the exploratory sweep's settings (`sweep_settings`) and a design's
follow-ups (`followup_plan`); where results are read and written (`paths`), the runs' checked
$XLA_FLAGS (`xla_flags`) and which commit (`commits`).
Imports nothing of launch or analyse."""
