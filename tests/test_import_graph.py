"""The package's import graph (every import between jaxsocial modules, inside functions too): it has no
cycle, the tools for people stand on the data layer only, the environment, the learners and the typed values
import nothing of the training run, and the floor count README states is the graph's."""

from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxsocial"
TOOLS = ("jaxsocial.render", "jaxsocial.playback", "jaxsocial.plot", "jaxsocial.plot_parts")
"""Tools for people, which stand on metrics, the run directory, policies and the environment only."""
BELOW_RUN = ("jaxsocial.env", "jaxsocial.agents", "jaxsocial.specs")
"""What acts and what is parsed, which know no run directory, config or program."""
ABOVE_TOOLS = (
    "jaxsocial.train",
    "jaxsocial.run.driver",
    "jaxsocial.run.loop",
    "jaxsocial.run.config",
    "jaxsocial.run.startup",
    "jaxsocial.experiments",
)


def _module(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def import_graph() -> dict[str, set[str]]:
    """Each module -> the jaxsocial modules it imports, at the top or inside a function (an import made late
    is an arrow all the same)."""
    graph = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                deps |= {alias.name for alias in node.names if alias.name.startswith("jaxsocial")}
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxsocial"):
                for alias in node.names:
                    name = f"{node.module}.{alias.name}"
                    deps.add(name if _is_module(name) else node.module)
        graph[_module(path)] = deps - {_module(path)}
    return graph


def floors(graph: dict[str, set[str]]) -> dict[str, int]:
    """Each module's floor: 0 without jaxsocial imports, else one above the highest module it imports.
    AssertionError naming the cycle if there is one."""
    out: dict[str, int] = {}

    def floor(module: str, path: tuple[str, ...]) -> int:
        assert module not in path, f"import cycle: {' -> '.join((*path, module))}"
        if module not in out:
            out[module] = 1 + max((floor(d, (*path, module)) for d in graph[module]), default=-1)
        return out[module]

    for module in graph:
        floor(module, ())
    return out


def test_no_cycle_and_readme_states_the_floors():
    levels = floors(import_graph())
    readme = (PACKAGE.parent / "README.md").read_text()
    stated = re.search(r"Imports, inside functions too, form (\d+) floors", readme)
    assert stated, "README's Layout states the number of floors"
    assert int(stated[1]) == max(levels.values()) + 1


def test_tools_for_people_stand_on_the_data_layer():
    graph = import_graph()

    def reach(module: str, seen: set[str]) -> set[str]:
        for dep in graph[module] - seen:
            seen.add(dep)
            reach(dep, seen)
        return seen

    for tool in TOOLS:
        above = sorted(m for m in reach(tool, set()) if m.startswith(ABOVE_TOOLS))
        assert not above, f"{tool} imports {above}"


def test_the_environment_learners_and_specs_know_no_training_run():
    for module, deps in import_graph().items():
        if module.startswith(BELOW_RUN):
            run = sorted(d for d in deps if d.startswith(("jaxsocial.run", "jaxsocial.train")))
            assert not run, f"{module} imports {run}"


def test_specs_are_text_and_build_no_environment():
    """`specs` parses and writes values (EnvSpec, PolicyRef, CheckpointRef) and imports no environment:
    `registry.env_params` builds an EnvSpec's parameters, so what parses text stays on the floor above it."""
    assert import_graph()["jaxsocial.specs"] <= {"jaxsocial.syntax"}


def test_readme_states_the_reading_lists_length():
    """README's "Reading the agent" lists the learner's files and their line count; both are the tree's."""
    readme = (PACKAGE.parent / "README.md").read_text()
    section = readme[readme.index("## Reading the agent") :]
    section = section[: section.index("\n## ", 1)]
    stated = re.search(r"is (\w+) files of `jaxsocial/agents/` \(([\d,]+) lines\)", section)
    assert stated, "README's Reading the agent states the files and their lines"
    files = re.findall(r"^\d\. `(\w+\.py)`", section, re.MULTILINE)
    words = {"three": 3, "four": 4, "five": 5, "six": 6}
    assert len(files) == words[stated.group(1)]
    lines = sum(len((PACKAGE / "agents" / name).read_text().splitlines()) for name in files)
    assert lines == int(stated.group(2).replace(",", ""))
