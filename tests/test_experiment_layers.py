"""The experiments in three layers, each a folder, as the work flows (issue 64, issue 83): plan (recipes,
designs, where results go, the runs' XLA flags, which commit) imports nothing of launch or analyse; analyse
(summaries, figures, records, statistics) imports nothing of launching (training processes, pinned runs,
in-flight GPU blocks, re-training): it reads what launch wrote and never starts it. Directly or through
another module."""

from test_import_graph import import_graph


def layer(graph: dict[str, set[str]], folder: str) -> tuple[str, ...]:
    """The modules of `jaxsocial/experiments/<folder>/`, its `__init__` included."""
    package = f"jaxsocial.experiments.{folder}"
    return tuple(m for m in graph if m == package or m.startswith(package + "."))


def reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    """Every module `start` imports, directly or through others."""
    seen, todo = set(), [start]
    while todo:
        for dep in graph.get(todo.pop(), set()) - seen:
            seen.add(dep)
            todo.append(dep)
    return seen


def test_analysis_never_imports_launch():
    graph = import_graph()
    launch = {*layer(graph, "launch"), "jaxsocial.train"}
    assert len(layer(graph, "analyse")) >= 10 and len(launch) >= 5
    crossings = {m: sorted(reachable(graph, m) & launch) for m in layer(graph, "analyse")}
    assert not any(crossings.values()), crossings


def test_the_plan_imports_neither_launch_nor_analysis():
    graph = import_graph()
    later = {*layer(graph, "launch"), *layer(graph, "analyse"), "jaxsocial.train"}
    assert len(layer(graph, "plan")) >= 7
    crossings = {m: sorted(reachable(graph, m) & later) for m in layer(graph, "plan")}
    assert not any(crossings.values()), crossings
