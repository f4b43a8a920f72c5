"""`--logger tensorboard` and `--logger wandb` (offline, no network): a tiny training run, then what each
wrote, read back in the library's own record format and compared with metrics.jsonl."""

import dataclasses
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY, TINY_ENV_ARGS

from jaxsocial import train
from jaxsocial.run import rundir

event_pb2 = pytest.importorskip("tensorboardX.proto.event_pb2")
wandb = pytest.importorskip("wandb")
wandb_pb2 = pytest.importorskip("wandb.proto.wandb_internal_pb2")


def trained(tmp_path: Path, logger: str) -> Path:
    """TINY trained with `logger` (2 chunks of 2 iterations): its run directory."""
    return train.run(dataclasses.replace(TINY, runs_dir=str(tmp_path), run_name=logger, logger=logger))


def logged_scalars(rows: list[dict]) -> dict[str, dict[int, float]]:
    """What a logger must have written: every finite numeric scalar of every metrics row, by iteration."""
    out: dict[str, dict[int, float]] = {}
    for row in rows:
        for key, value in row.items():
            if isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(value):
                out.setdefault(key, {})[row["iteration"]] = value
    return out


def tfrecords(path: Path):
    """The records of a TFRecord file (u64 length, u32 crc, data, u32 crc each)."""
    raw = path.read_bytes()
    pos = 0
    while pos < len(raw):
        (length,) = struct.unpack("<Q", raw[pos : pos + 8])
        yield raw[pos + 12 : pos + 12 + length]
        pos += 12 + length + 4


def test_tensorboard_event_files_hold_every_metric(tmp_path):
    run_dir = trained(tmp_path, "tensorboard")
    (events,) = (run_dir / "tensorboard").glob("events.out.tfevents.*")
    scalars: dict[str, dict[int, float]] = {}
    texts = []
    for record in tfrecords(events):
        event = event_pb2.Event.FromString(record)
        for value in event.summary.value:
            if value.HasField("tensor") and value.tensor.string_val:
                texts.append(value.tensor.string_val[0].decode())
            else:
                scalars.setdefault(value.tag, {})[event.step] = value.simple_value
    expected = logged_scalars(rundir.read_metrics(run_dir))
    assert set(scalars) == set(expected) and {"return/0", "policy_loss/0", "env_steps_per_s"} <= set(scalars)
    for tag, by_step in expected.items():  # stored as float32
        assert scalars[tag] == {step: float(np.float32(v)) for step, v in by_step.items()}, tag
    assert len(texts) == 1 and json.dumps(TINY_ENV_ARGS) in texts[0]  # the run's config, as JSON


def wandb_records(path: Path):
    """The records of a .wandb file: a 7-byte header, then LevelDB log blocks of 32 KiB whose chunks have a
    7-byte header (crc u32, length u16, type u8: 1 full, 2 first, 3 middle, 4 last)."""
    raw, block, pos, pending = path.read_bytes(), 32768, 7, b""
    while pos + 7 <= len(raw):
        if block - pos % block < 7:
            pos += block - pos % block
            continue
        _, length, kind = struct.unpack("<IHB", raw[pos : pos + 7])
        if kind == 0:
            break
        data, pos = raw[pos + 7 : pos + 7 + length], pos + 7 + length
        pending = data if kind in (1, 2) else pending + data
        if kind in (1, 4):
            yield wandb_pb2.Record.FromString(pending)


def test_wandb_offline_run_holds_every_metric_and_the_config(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    run_dir = trained(tmp_path, "wandb")
    wandb.teardown()  # wandb 0.31 writes the offline run file in its service process, flushed when it stops
    (log,) = (run_dir / "wandb").glob("offline-run-*/run-*.wandb")
    history, config = {}, {}
    for record in wandb_records(log):
        kind = record.WhichOneof("record_type")
        if kind == "history":
            items = {i.key or "/".join(i.nested_key): json.loads(i.value_json) for i in record.history.item}
            history[items.pop("_step")] = {k: v for k, v in items.items() if not k.startswith("_")}
        elif kind == "run":
            config = {u.key: json.loads(u.value_json) for u in record.run.config.update}
    expected = logged_scalars(rundir.read_metrics(run_dir))
    assert {k for row in history.values() for k in row} == set(expected)
    for key, by_step in expected.items():
        assert {step: history[step][key] for step in by_step} == by_step, key
    assert config["env_args"] == TINY_ENV_ARGS and config["num_envs"] == TINY.num_envs
