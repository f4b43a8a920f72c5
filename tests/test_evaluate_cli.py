"""`python -m jaxsocial.evaluate` output: a table on stdout, the JSON only in --out."""

import dataclasses
import json
from pathlib import Path

import pytest
import tyro

from jaxsocial import evaluate
from jaxsocial.env import registry
from jaxsocial.specs import PolicyRef

ARGS = [
    "--env",
    "goalcycle3",
    "--env-args",
    "max_steps=10,width=7,height=7",
    "--slots",
    "random,random,random",
]
ARGS += ["--episodes", "4"]


def test_table_on_stdout_and_json_in_out(tmp_path, capsys):
    out = tmp_path / "eval.json"
    evaluate.main([*ARGS, "--out", str(out)])
    printed = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert (
        not printed.lstrip().startswith("{") and len(printed.splitlines()) == 2 + 3 + 1
    )  # head, rows, wrote
    for slot in result["results"]:  # every slot's mean and interval, as printed with two decimals
        low, high = slot["ci95"]
        assert f"{slot['mean_return']:.2f} [{low:.2f}, {high:.2f}]" in printed
    assert "95% intervals over episodes" in printed and f"wrote {out}" in printed
    with pytest.raises(SystemExit, match="--overwrite"):
        evaluate.main([*ARGS, "--out", str(out)])


def test_ct_table_names_the_scores():
    def interval(mean):
        return {"mean": mean, "ci95": [mean - 0.01, mean + 0.01]}

    cases = {
        name: {"episode": interval(1.0), "second_half": interval(0.5)} for name in ("with", "dropout", "solo")
    }
    result = {
        "env": "goalcycle3", "env_args": "", "checkpoints": ["a", "b"], "policy_iterations": [200, 200],
        "episodes_per_checkpoint": 64, "protocol": "ct", "ct": interval(0.125), "recall": interval(-0.25),
        "learner_returns": cases, "expert_return": {"episode": 36.8, "second_half": 18.0}, "ci_over": "seeds",
    }  # fmt: skip
    table = evaluate.format_table(result)
    assert "CT score  0.125 [0.115, 0.135]" in table and "recall    -0.250 [-0.260, -0.240]" in table
    assert "over training seeds" in table and "training iteration 200, 200" in table and "36.80" in table


def _interval(mean: float, half: float = 0.01) -> dict:
    return {"mean": mean, "ci95": [mean - half, mean + half]}


CT = "next: does it learn from the experts, and keep it once they leave? python -m jaxsocial.evaluate --ckpt runs/a runs/b --env goalcycle3:width=9,height=9 --protocol ct"  # noqa: E501
ONWARDS = "next: compare conditions over fresh seeds, with a test: docs/your-experiment.md"


def test_the_outcome_says_what_the_evaluation_shows():
    cfg = evaluate.EvalConfig(ckpt=("runs/a", "runs/b"), env="goalcycle3", env_args="width=9,height=9")
    assert cfg.ckpt == (PolicyRef(Path("runs/a")), PolicyRef(Path("runs/b")))  # text is parsed once
    ct = {"protocol": "ct", "ct": _interval(0.125), "recall": _interval(0.0, 0.05)}
    said = evaluate.result_lines(ct, cfg)
    assert "follows them rather than having learned the task" in said[0]
    assert said[1] == ONWARDS  # after the CT protocol: onwards (render points back here)
    assert "--out FILE" in said[2]
    kept = evaluate.result_lines({**ct, "recall": _interval(0.2)}, cfg)[0]
    assert "keeps part of it after they leave" in kept
    assert "no difference" in evaluate.result_lines({**ct, "ct": _interval(0.0, 0.1)}, cfg)[0]
    slots = [
        {"kind": "learner", "mean_return": 3.0, "episodes": 4},
        {"kind": "expert", "mean_return": 30.0, "episodes": 4},
        {"kind": "expert", "mean_return": 32.0, "episodes": 4},
    ]
    said = evaluate.result_lines({"results": slots}, dataclasses.replace(cfg, out="x.json"))
    assert said == [
        "the learner scored 3.00 per episode beside experts scoring 31.00",
        "past the one-tile plateau (return > 2): it completes the cycle here, 10% of the experts' return",
        CT,
    ]
    randoms = [{**s, "kind": "random"} if s["kind"] == "expert" else s for s in slots]
    assert evaluate.result_lines({"results": randoms}, dataclasses.replace(cfg, out="x.json")) == [ONWARDS]
    four = registry.env_params("goalcycle4")
    below = evaluate.learning_verdict(-4.93, 45.5, four)
    assert below.startswith("on the one-tile plateau (return <= 2): it does not complete the 4-goal cycle")
    assert below.endswith("; below 0 it pays more wrong-tile penalties than it earns")
    rooms = registry.env_params("fourrooms")
    assert evaluate.learning_verdict(0.5, 0.9, rooms) == "that is 56% of the experts' return"


def test_a_mistyped_flag_names_the_module_to_ask_for_help(capsys):
    with pytest.raises(SystemExit):
        evaluate.main(["--episode", "3"])
    err = capsys.readouterr().err
    assert "--episodes" in err and "python -m jaxsocial.evaluate --help" in err and "evaluate.py" not in err


def test_the_command_line_gives_parsed_policies():
    cfg = tyro.cli(evaluate.EvalConfig, args=["--ckpt", "runs/a#1", "runs/b"])
    assert cfg.ckpt == (PolicyRef(Path("runs/a"), 1), PolicyRef(Path("runs/b")))
