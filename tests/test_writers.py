"""score_jax.writers: CSV round trips and resume, TensorBoard and W&B files read back."""

import glob
import importlib.util
import math
import os
import struct
import time

import numpy as np
import pytest

from score_jax.run import writers
from score_jax.run.writers import CsvWriter, MultiWriter, make_writers, read_csv

HAS_WANDB = importlib.util.find_spec("wandb") is not None


def _nan_equal(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


# --- CSV --------------------------------------------------------------------------------------


def test_csv_round_trip_with_seed_column(tmp_path):
    path = os.path.join(tmp_path, "run", "metrics.csv")
    rows = [
        (0, {"episode_return": 1.5, "loss": float("nan"), "updates": 3}),
        (100, {"episode_return": -2.25, "loss": 0.125, "updates": np.int64(7)}),
    ]
    with CsvWriter(path) as w:
        for step, m in rows:
            w.write(step, m, seed=4)
    with open(path) as f:
        lines = f.read().splitlines()
    assert lines[0] == "env_steps,seed,episode_return,loss,updates"
    assert lines[1] == "0,4,1.5,nan,3"
    back = read_csv(path)
    assert [r["env_steps"] for r in back] == [0, 100] and {r["seed"] for r in back} == {4}
    for (_, m), r in zip(rows, back, strict=True):
        assert all(_nan_equal(float(v), r[k]) for k, v in m.items())


def test_csv_columns_order_and_missing_values(tmp_path):
    path = os.path.join(tmp_path, "m.csv")
    with CsvWriter(path, columns=["b", "a"]) as w:
        w.write(5, {"a": 1.0, "env_steps": 5})  # a repeated env_steps is accepted
        w.write(6, {"b": 2.0})
    with open(path) as f:
        assert f.read().splitlines() == ["env_steps,b,a", "5,nan,1.0", "6,2.0,nan"]
    with pytest.raises(ValueError, match="contradicts"):
        CsvWriter(path).write(7, {"env_steps": 8})


def test_csv_resume_appends_keeps_header_and_refuses_unknown_keys(tmp_path):
    path = os.path.join(tmp_path, "m.csv")
    with CsvWriter(path) as w:
        for step in (10, 20, 30):
            w.write(step, {"r": step / 10})
    w = CsvWriter(path)
    assert w.truncate(20) == 2
    w.write(30, {"r": 3.5})
    with pytest.raises(ValueError, match=r"keys \['q'\].*columns \['env_steps', 'r'\]"):
        w.write(40, {"r": 4.0, "q": 1.0})
    with pytest.raises(ValueError, match="has no 'seed' column"):
        w.write(40, {"r": 4.0}, seed=1)
    w.close()
    assert [(r["env_steps"], r["r"]) for r in read_csv(path)] == [(10, 1.0), (20, 2.0), (30, 3.5)]
    with open(path) as f:
        assert f.readline().strip() == "env_steps,r"
    assert writers.truncate_csv(path, -1) == 0
    assert read_csv(path) == []
    with CsvWriter(path, overwrite=True) as w:
        w.write(1, {"other": 1.0})
    assert read_csv(path) == [{"env_steps": 1.0, "other": 1.0}]


# --- TensorBoard ------------------------------------------------------------------------------


def _read_tfrecords(path: str) -> list[bytes]:
    """The records of a TFRecord file (length, masked CRC of it, data, masked CRC of it)."""
    from tensorboardX.record_writer import masked_crc32c

    out = []
    with open(path, "rb") as f:
        data = f.read()
    pos = 0
    while pos < len(data):
        header = data[pos : pos + 8]
        (length,) = struct.unpack("<Q", header)
        (crc,) = struct.unpack("<I", data[pos + 8 : pos + 12])
        assert crc == masked_crc32c(header)
        body = data[pos + 12 : pos + 12 + length]
        (crc,) = struct.unpack("<I", data[pos + 12 + length : pos + 16 + length])
        assert crc == masked_crc32c(body)
        out.append(body)
        pos += 16 + length
    return out


def _tb_scalars(run_dir: str) -> dict[str, list[tuple[int, float]]]:
    """``{tag: [(step, value)]}`` from the event files of one run directory: through
    tensorboard's EventAccumulator when tensorboard is installed, else a TFRecord reader."""
    try:
        from tensorboard.backend.event_processing import event_accumulator
    except ImportError:
        event_accumulator = None
    if event_accumulator is not None:
        acc = event_accumulator.EventAccumulator(run_dir)
        acc.Reload()
        return {t: [(e.step, e.value) for e in acc.Scalars(t)] for t in acc.Tags()["scalars"]}
    from tensorboardX.proto import event_pb2

    out: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(glob.glob(os.path.join(run_dir, "events.out.tfevents.*"))):
        for record in _read_tfrecords(path):
            event = event_pb2.Event.FromString(record)
            for v in event.summary.value:
                out.setdefault(v.tag, []).append((event.step, v.simple_value))
    return out


def test_tensorboard_event_files_read_back(tmp_path):
    logdir = os.path.join(tmp_path, "tb")
    with writers.TensorBoardWriter(logdir) as w:
        for step in (0, 50, 100):
            loss = float("nan") if step else 1.0
            w.write(step, {"episode_return": step / 4, "critic_loss": loss})
            w.write(step, {"eval/return": step + 0.5}, seed=3)
    root = _tb_scalars(logdir)
    assert root["train/episode_return"] == [(0, 0.0), (50, 12.5), (100, 25.0)]
    assert root["train/critic_loss"] == [(0, 1.0)]  # NaN skipped
    assert "eval/return" not in root
    seed = _tb_scalars(os.path.join(logdir, "seed_3"))
    assert seed == {"eval/return": [(0, 0.5), (50, 50.5), (100, 100.5)]}


# --- W&B --------------------------------------------------------------------------------------


def _wandb_history(path: str) -> list[dict[str, float]]:
    """History rows of an offline ``.wandb`` file (LevelDB log records of wandb's Record proto
    after a 7-byte header)."""
    from wandb.proto import wandb_internal_pb2

    with open(path, "rb") as f:
        data = f.read()
    assert data[:4] == b":W&B"
    chunks, pending, pos, block = [], b"", 7, 32768
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # block trailer padding
            pos += block - pos % block
            continue
        length, kind = int.from_bytes(data[pos + 4 : pos + 6], "little"), data[pos + 6]
        if pos + 7 + length > len(data):  # still being written
            break
        body, pos = data[pos + 7 : pos + 7 + length], pos + 7 + length
        if kind == 1:
            chunks.append(body)
        elif kind in (2, 3):
            pending = (pending if kind == 3 else b"") + body
        elif kind == 4:
            chunks.append(pending + body)
    rows = []
    for chunk in chunks:
        record = wandb_internal_pb2.Record.FromString(chunk)
        if record.WhichOneof("record_type") == "history":
            items = {i.key or "/".join(i.nested_key): i.value_json for i in record.history.item}
            rows.append({k: float(v) for k, v in items.items() if not k.startswith("_")})
    return rows


@pytest.mark.skipif(not HAS_WANDB, reason="wandb is not installed (pip install -e .[tracking])")
def test_wandb_offline_writes_its_run_directory(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_API_KEY", "")  # no credentials: nothing may need them
    monkeypatch.setenv("WANDB_BASE_URL", "http://127.0.0.1:9")  # a network call would fail
    w = writers.WandbWriter("score-jax-test", str(tmp_path), config={"lr": 3e-4}, mode=None)
    assert w.mode == "offline"
    w.write(0, {"episode_return": 1.0, "loss": float("nan")})
    w.write(10, {"episode_return": 2.0, "loss": 0.5}, seed=2)
    w.close()
    files = glob.glob(os.path.join(tmp_path, "wandb", "offline-run-*", "run-*.wandb"))
    assert len(files) == 1
    # run.finish() can return before wandb's service process has written the file out
    deadline = time.monotonic() + 30.0
    while len(_wandb_history(files[0])) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _wandb_history(files[0]) == [
        {"env_steps": 0.0, "train/episode_return": 1.0},
        {"env_steps": 10.0, "seed_2/train/episode_return": 2.0, "seed_2/train/loss": 0.5},
    ]


def test_wandb_missing_gives_the_install_hint(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_wandb(name, *args, **kwargs):
        if name == "wandb":
            raise ImportError("No module named 'wandb'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_wandb)
    with pytest.raises(ImportError, match=r"pip install -e \"\.\[tracking\]\""):
        writers.WandbWriter("p", "/nonexistent")


# --- fan-out ----------------------------------------------------------------------------------


def test_make_writers_always_includes_csv_and_rejects_unknown_kinds(tmp_path):
    known = "unknown writer kind.*'mlflow'.*known: csv, tensorboard, wandb"
    with pytest.raises(ValueError, match=known):
        make_writers(["tensorboard", "mlflow"], str(tmp_path))
    assert not os.listdir(tmp_path)  # nothing was created
    multi = make_writers(["tensorboard"], str(tmp_path))
    assert [type(w).__name__ for w in multi.writers] == ["CsvWriter", "TensorBoardWriter"]
    assert isinstance(multi, writers.MetricWriter)
    multi.write(1, {"episode_return": 3.0}, seed=0)
    multi.close()
    assert read_csv(os.path.join(tmp_path, "metrics.csv")) == [
        {"env_steps": 1.0, "seed": 0.0, "episode_return": 3.0}
    ]
    assert _tb_scalars(os.path.join(tmp_path, "tensorboard", "seed_0")) == {
        "train/episode_return": [(1, 3.0)]
    }
    with make_writers([], str(tmp_path)) as only_csv:
        assert [type(w).__name__ for w in only_csv.writers] == ["CsvWriter"]


def test_multi_writer_closes_all_then_reraises():
    closed = []

    class Failing:
        def write(self, step, metrics, seed=None):
            pass

        def close(self):
            closed.append("failing")
            raise OSError("disk full")

    class Ok(Failing):
        def close(self):
            closed.append("ok")

    with pytest.raises(OSError, match="disk full"):
        MultiWriter([Failing(), Ok()]).close()
    assert closed == ["failing", "ok"]
