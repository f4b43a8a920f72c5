"""The paper's experiments, one command per figure.

    python -m jaxsocial.experiments list
    python -m jaxsocial.experiments run h1 --scale cpu --seeds 3      # train what is missing, resume the rest
    python -m jaxsocial.experiments figure h1 --scale cpu --seeds 3   # JSON summary + PNG from the run dirs

`recipes` names the conditions and scales, `runner` trains and evaluates them, `figures` summarises and
draws them, `predictions` draws a learner's predicted next frames.
"""
