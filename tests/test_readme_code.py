"""README's Python blocks run as written, and give what their comments say (shapes, dtypes, agents)."""

from __future__ import annotations

import re
from pathlib import Path

import jax.numpy as jnp
import pytest
from doc_sections import sections

README = Path(__file__).resolve().parents[1] / "README.md"
PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```$", re.M | re.S)


def python_blocks() -> dict[str, str]:
    """README heading -> the Python block in its section (one a section)."""
    blocks = {}
    for heading, text in sections(README):
        found = PYTHON_BLOCK.findall(text)
        assert len(found) <= 1, f"{len(found)} Python blocks under {heading!r}: give each a test"
        if found:
            blocks[heading] = found[0]
    return blocks


def run(heading: str) -> dict:
    """The names the block under `heading` leaves, run in a fresh namespace."""
    namespace: dict = {}
    exec(compile(python_blocks()[heading], f"README.md, {heading}", "exec"), namespace)
    return namespace


def test_every_python_block_has_a_test_here():
    assert set(python_blocks()) == {"The environment in ten lines", "Inside gymnax and JaxMARL"}


def test_the_environment_in_ten_lines():
    names = run("The environment in ten lines")
    assert names["obs"].shape == (3, 21, 21, 3) and names["obs"].dtype == jnp.uint8
    assert names["reward"].shape == (3,) and names["reward"].dtype == jnp.float32
    assert names["terminated"].shape == (3,) and names["terminated"].dtype == jnp.bool_
    assert names["truncated"].shape == () and names["truncated"].dtype == jnp.bool_
    assert names["info"]["final_obs"].shape == names["obs"].shape


@pytest.mark.slow  # imports gymnax and JaxMARL (about 3 s) and compiles both libraries' steps
def test_inside_gymnax_and_jaxmarl():
    names = run("Inside gymnax and JaxMARL")
    assert names["info"]["rewards"].shape == (3,) and names["info"]["rewards"].dtype == jnp.float32
    assert names["marl"].agents == ["agent_0", "agent_1", "agent_2"]
    assert names["obs"]["agent_0"].shape == (21, 21, 3) and names["obs"]["agent_0"].dtype == jnp.uint8
    assert set(names["rewards"]) >= set(names["marl"].agents)
