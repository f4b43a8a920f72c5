"""The command-line mini-languages (slots, experts, stages, assignments, per-layer conv_impl, policy and
checkpoint references) each have one parser and one formatter, and formatting then parsing gives back what
was parsed (hypothesis); their two shared syntaxes, `key=value,...` and `NAME[:ARGS]`, have one parser each
(`jaxsocial.syntax`); a whole TrainConfig's derived command line gives the config back."""

import json
import string
from pathlib import Path

import pytest
from conftest import needs_records
from hypothesis import given
from hypothesis import strategies as st

import jaxsocial
from jaxsocial import evaluate, syntax, train
from jaxsocial.agents import expert_spec, network_config, population
from jaxsocial.env import registry
from jaxsocial.run import config, flags, rundir, schedule
from jaxsocial.run.flags import config_flags
from jaxsocial.specs import ENV_ARGS, CheckpointRef, EnvSpec, PolicyRef

probabilities = st.floats(0.0, 1.0, allow_nan=False)
experts_ = st.builds(expert_spec.ExpertSpec, st.sampled_from(expert_spec.KINDS), probabilities, probabilities)
paths = st.text(string.ascii_letters + string.digits + "/_-.=", min_size=1, max_size=12).map(Path)
policies = st.builds(PolicyRef, paths, st.integers(0, 99))
checkpoints = st.builds(CheckpointRef, paths, st.one_of(st.none(), st.integers(0, 10**6)))
slots = st.one_of(
    st.sampled_from([population.Slot("learner"), population.Slot("random")]),
    st.builds(lambda p: population.Slot("frozen", p), policies),
    st.builds(lambda e: population.Slot("expert", expert=e), experts_),
)
values = st.one_of(
    st.integers(-(10**6), 10**6), st.floats(allow_nan=False, allow_infinity=False), st.booleans()
)
keys = st.text(string.ascii_lowercase + "_", min_size=1, max_size=10)
overrides = st.dictionaries(keys, values, min_size=1, max_size=4)
thresholds = st.floats(-1e6, 1e6, allow_nan=False)
words = st.text(string.ascii_letters + string.digits + "_-.:/#@' ", min_size=1, max_size=12).map(str.strip)
"""Keys and values as text: anything but ',' and '=', without surrounding whitespace ('' included)."""
conv_impls = st.dictionaries(
    st.sampled_from(network_config.CONV_LAYERS),
    st.sampled_from((*network_config.CONV_IMPLS, "auto")),
    min_size=1,
)
REPO = Path(__file__).resolve().parents[1]


@st.composite
def stage_lists(draw):
    starts = sorted(draw(st.sets(st.integers(0, 10**5), max_size=3)))
    stages = [schedule.Stage(tuple(draw(overrides).items()), start=s) for s in starts]
    for threshold in draw(st.lists(thresholds, max_size=2)):
        stages.append(schedule.Stage(tuple(draw(overrides).items()), threshold=threshold))
    return tuple(stages)


@given(st.lists(slots, min_size=1, max_size=6))
def test_slots_round_trip(drawn):
    drawn = tuple(drawn)
    assert population.parse_slots(population.format_slots(drawn), len(drawn), need_learner=False) == drawn


@given(policies, checkpoints)
def test_references_round_trip(policy, checkpoint):
    assert PolicyRef.parse(str(policy)) == policy and CheckpointRef.parse(str(checkpoint)) == checkpoint


@given(st.sampled_from(jaxsocial.registered_envs()), st.one_of(st.just({}), overrides))
def test_env_specs_round_trip(name, args):
    spec = EnvSpec(name, tuple(args.items()))
    assert EnvSpec.parse(str(spec)) == spec


def test_references_say_what_they_mean():
    assert str(PolicyRef(Path("runs/a"), 2)) == "runs/a#2" and str(PolicyRef(Path("runs/a"))) == "runs/a"
    assert str(CheckpointRef(Path("runs/a"), 600)) == "runs/a@600"
    assert PolicyRef.parse("runs/x#y") == PolicyRef(
        Path("runs/x#y")
    )  # not a learner number: part of the path
    with pytest.warns(DeprecationWarning, match="write the learner as runs/a#2"):
        assert PolicyRef.parse("runs/a@2") == PolicyRef(Path("runs/a"), 2)
    with pytest.raises(ValueError, match="whole number"):
        CheckpointRef.parse("runs/a@last")


@given(experts_)
def test_experts_round_trip(expert):
    assert expert_spec.parse_expert(str(expert)) == expert


@given(stage_lists())
def test_stages_round_trip(stages):
    assert schedule.parse_stages(schedule.format_stages(stages)) == stages


@given(overrides)
def test_env_args_round_trip(values_):
    pairs = tuple(values_.items())
    assert ENV_ARGS.parse(ENV_ARGS.format(pairs)) == pairs
    assert syntax.parse_assignments(syntax.format_assignments(values_, repr), syntax.literal) == list(pairs)


@given(st.dictionaries(words.filter(bool), words, max_size=4), st.lists(words, min_size=1, max_size=3))
def test_assignments_and_names_round_trip(values_, bare):
    text = syntax.format_assignments(values_)
    assert syntax.parse_assignments(text) == list(values_.items())
    spaced = ", ".join([*(f" {k} = {v} " for k, v in values_.items()), *bare])
    assert syntax.parse_assignments(spaced, bare=True) == [*values_.items(), *((None, v) for v in bare)]
    assert syntax.split_name(f"name:{text}") == ("name", text) and syntax.split_name("name") == ("name", "")


@given(conv_impls)
def test_conv_impls_round_trip(impls):
    unnamed = dict.fromkeys(network_config.CONV_LAYERS, "matmul")  # the layers not named
    assert network_config.parse_conv_impl(network_config.format_conv_impl(impls)) == {**unnamed, **impls}


def test_assignments_refuse_what_is_not_field_value():
    assert syntax.parse_assignments(" ,a = 1,, b=x=y:z ,") == [("a", "1"), ("b", "x=y:z")]
    with pytest.raises(ValueError, match="entry 'b' is not field=value"):
        syntax.parse_assignments("a=1,b")
    for make in (config.TrainConfig, evaluate.EvalConfig):  # a bad --env names the flag it came from
        with pytest.raises(ValueError, match="--env goalcycle3:penalty: entry 'penalty' is not field=value"):
            make(env="goalcycle3:penalty")
    assert syntax.parse_assignments("xla,", bare=True) == [(None, "xla"), (None, "")]  # nothing skipped
    with pytest.raises(ValueError, match="unknown implementation ''"):
        network_config.parse_conv_impl("xla,")
    assert ENV_ARGS.parse("penalty=0.5,agent_colors=fixed,penalty=-1") == (
        ("penalty", -1),
        ("agent_colors", "fixed"),
    )


def test_formatting_is_the_syntax_users_write():
    text = "learner,expert:explorer:epsilon=0.2,forget=0.01,random,frozen:runs/h1/s0#1"
    assert population.format_slots(population.parse_slots(text, 4)) == text
    curriculum = "0:penalty=0.5;return>=10.0:penalty=1.0"
    assert schedule.format_stages(schedule.parse_stages(curriculum)) == curriculum


@pytest.mark.parametrize(
    "argv",
    [
        *(["--preset", name] for name in config.PRESETS),
        [
            "--preset",
            "laptop",
            "--env",
            "goalcycle3-solo",
            "--env-args",
            "penalty=0,max_steps=40",
            "--seed",
            "7",
        ],
        [
            "--slots",
            "learner,expert:explorer:epsilon=0.2,forget=0.01,random",
            "--stages",
            "0:penalty=0.5;return>=2.5:solo_prob=0.75",
        ],
        [
            "--stop-at-return",
            "5",
            "--no-progress",
            "--resume",
            "--init-from",
            "runs/x@30",
            "--logger",
            "tensorboard",
        ],
        [
            "--eval-envs",
            "goalcycle4:width=7,height=7",
            "goalcycle3-solo",
            "--eval-every",
            "3",
            "--eval-episodes",
            "2",
        ],
        ["--env-args", "observation='symbolic'", "--net.obs", "rgb"],  # a view other than the environment's
        ["--env-args", "observation='symbolic'"],  # the parser derives net.obs from the environment
        [
            "--net.conv-channels",
            "4",
            "4",
            "4",
            "--net.aux",
            "pred+attention",
            "--ppo.lr",
            "1e-05",
            "--algo",
            "bc",
        ],
    ],
)
def test_a_configs_command_line_gives_it_back(argv):
    cfg = train.parse_args(argv)
    flags = config_flags(cfg)
    assert train.parse_args(flags) == cfg
    assert flags[:2] == ["--preset", cfg.preset]


OLD_FLAGS = ["--net.chunk", "64", "--ppo.chunk-length=8", "--ppo.minibatch-chunks", "32"]
NEW_FLAGS = ["--net.frame-batch", "64", "--ppo.segment-length=8", "--ppo.minibatch-segments", "32"]


def test_the_old_flags_of_renamed_fields_still_parse(capsys):
    """`--net.chunk`, `--ppo.chunk-length` and `--ppo.minibatch-chunks` (also as --flag=value, as committed
    summaries and scripts write them) give the config of today's flags, each with a deprecation message."""
    new = train.parse_args(NEW_FLAGS)
    assert "deprecated" not in capsys.readouterr().err
    assert (new.net.frame_batch, new.ppo.segment_length, new.ppo.minibatch_segments) == (64, 8, 32)
    assert train.parse_args(OLD_FLAGS) == new
    err = capsys.readouterr().err
    for old, today in flags.LEGACY_FLAGS.items():
        assert f"{old} is deprecated" in err and f"use {today}" in err
    assert config_flags(new)[-6:] == ["--net.frame-batch", "64", "--ppo.minibatch-segments", "32",
                                      "--ppo.segment-length", "8"]  # fmt: skip


def test_a_config_json_with_the_old_field_names_reads_as_today():
    """config.json written before the renames (`ppo.chunk_length`, `ppo.minibatch_chunks`, `net.chunk`:
    committed records, older run directories) gives the TrainConfig of today's names, and `--resume` finds no
    conflict between it and today's; config.json is written with today's names."""
    cfg = train.parse_args(NEW_FLAGS)
    new = config.config_dict(cfg)
    assert {"segment_length", "minibatch_segments"} <= set(new["ppo"]) and "frame_batch" in new["net"]
    old = json.loads(json.dumps(new))
    old["net"]["chunk"] = old["net"].pop("frame_batch")
    old["ppo"]["chunk_length"] = old["ppo"].pop("segment_length")
    old["ppo"]["minibatch_chunks"] = old["ppo"].pop("minibatch_segments")
    assert config.modern_keys(old) == new
    assert config.config_from_dict(old) == config.config_from_dict(new) == cfg
    assert config.resume_conflicts(old, new) == []
    old["ppo"]["chunk_length"] = 16
    assert config.resume_conflicts(old, new) == ["ppo.segment_length"]  # named as today


@needs_records("records/tiny")
def test_a_committed_records_config_with_the_old_field_names_reads_as_today():
    """A committed tiny record's config.json, written before the renames, reads under today's names."""
    record = rundir.read_config(REPO / "benchmarks/results/records/tiny/social_pred_nopenalty-s0-1/s0")
    assert "chunk" in record["net"] and "chunk_length" in record["ppo"]  # written before the renames
    read = config.config_from_dict(record)
    assert read.net.frame_batch == record["net"]["chunk"]
    assert (read.ppo.segment_length, read.ppo.minibatch_segments) == (
        record["ppo"]["chunk_length"],
        record["ppo"]["minibatch_chunks"],
    )


@pytest.mark.parametrize("preset", ["small", "laptop"])
def test_an_environment_with_overrides_is_one_syntax(preset, capsys):
    """`--env NAME:ARGS` is `--env NAME --env-args ARGS` (replacing a preset's overrides, as --env-args
    does) for training and evaluation; with `--env-args` as well, the fields join; a field in both errs."""
    flag = ["--preset", preset, "--env", "goalcycle4", "--env-args", "penalty=1.0,width=9"]
    as_flag = train.parse_args(flag)
    assert train.parse_args(["--preset", preset, "--env", "goalcycle4:penalty=1.0,width=9"]) == as_flag
    assert (as_flag.env, as_flag.env_args) == ("goalcycle4", (("penalty", 1.0), ("width", 9)))
    split = ["--preset", preset, "--env=goalcycle4:penalty=1.0", "--env-args", "width=9"]
    assert train.parse_args(split) == as_flag
    with pytest.raises(SystemExit):
        train.parse_args(["--preset", preset, "--env", "goalcycle4:width=9", "--env-args", "width=7"])
    assert "both set width: give each field once" in capsys.readouterr().err.replace("\n", " ")
    assert evaluate.EvalConfig(env="goalcycle4:penalty=1.0", env_args="width=9") == evaluate.EvalConfig(
        env="goalcycle4", env_args="penalty=1.0,width=9"
    )


def test_an_unknown_environment_shows_both_forms():
    spec = EnvSpec.parse("goalcycle9:penalty=1.0")
    with pytest.raises(ValueError, match="unknown environment") as err:
        registry.env_params(spec.name, spec.args)
    assert "(goalcycle3:penalty=1.0,width=7), or in --env-args" in str(err.value)
