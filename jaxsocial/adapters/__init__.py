"""The environments inside other JAX RL libraries; each module imports its library, so import the one you use:

- `jaxsocial.adapters.gymnax_env`: one learner's view as a gymnax 1.x `Environment`, its companions (scripted
  experts, frozen policies, random distractors) stepping inside (`pip install -e ".[gymnax]"`);
- `jaxsocial.adapters.jaxmarl_env`: every agent as a JaxMARL `MultiAgentEnv` agent (`pip install -e
  ".[jaxmarl]"`).
"""
