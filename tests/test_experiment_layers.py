"""The experiments in three layers, as the work flows (issue 64): plan (recipes, designs, where results go,
the runs' XLA flags, which commit) imports nothing of launch or analysis; analysis (summaries, figures,
records, statistics) imports nothing of launching (training processes, pinned runs, in-flight GPU blocks,
re-training): it reads what launch wrote and never starts it. Directly or through another module."""

from test_import_graph import import_graph

PLAN = (
    "jaxsocial.experiments.paths",
    "jaxsocial.experiments.xla_flags",
    "jaxsocial.experiments.commits",
    "jaxsocial.experiments.catalogue",
    "jaxsocial.experiments.prereg",
    "jaxsocial.experiments.conditions",
    "jaxsocial.experiments.recipes",
)
ANALYSE = (
    "jaxsocial.experiments.summaries",
    "jaxsocial.experiments.kinds",
    "jaxsocial.experiments.plot_figures",
    "jaxsocial.experiments.records",
    "jaxsocial.experiments.run_times",
    "jaxsocial.experiments.rundirs",
    "jaxsocial.experiments.takeoff",
    "jaxsocial.experiments.takeoff_power",
    "jaxsocial.experiments.predictions",
)
LAUNCH = (
    "jaxsocial.experiments.runner",
    "jaxsocial.experiments.pinned",
    "jaxsocial.experiments.inflight",
    "jaxsocial.experiments.verify",
    "jaxsocial.train",
)


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
    assert all(module in graph for module in (*ANALYSE, *LAUNCH))
    crossings = {m: sorted(reachable(graph, m) & set(LAUNCH)) for m in ANALYSE}
    assert not any(crossings.values()), crossings


def test_the_plan_imports_neither_launch_nor_analysis():
    graph = import_graph()
    assert all(module in graph for module in PLAN)
    crossings = {m: sorted(reachable(graph, m) & {*LAUNCH, *ANALYSE}) for m in PLAN}
    assert not any(crossings.values()), crossings
