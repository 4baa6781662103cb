"""The conventions RL users expect (issue 14), the parts that need no training: console
scripts and extras, the compilation cache, provenance, the start-of-run header, --describe and
sub-space units, tracking checks, LICENSE / CHANGELOG / README, benchmark output folders."""

import dataclasses
import glob
import importlib
import importlib.metadata
import os
import re
import subprocess

import jax
import pytest
import tomllib

import envs
from score_jax.cli import eval as eval_cli
from score_jax.cli import robustness as robustness_cli
from score_jax.cli import train as train_cli
from score_jax.cli import transfer as transfer_cli
from score_jax.core.spaces import CompositeSpace
from score_jax.evaluation.transfer import TransferArgs
from score_jax.run import compile_cache
from score_jax.run import provenance as prov_lib
from score_jax.run.config import TrainConfig, resolve
from score_jax.run.provenance import git_info, provenance
from score_jax.run.summary import announce, header_lines
from score_jax.run.writers import check_kinds

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PYPROJECT = tomllib.load(open(os.path.join(ROOT, "pyproject.toml"), "rb"))
README = open(os.path.join(ROOT, "README.md")).read()


# --- 1. console scripts, 8. extras, 9. licence ------------------------------------------------


def test_console_scripts_point_at_cli_functions():
    scripts = PYPROJECT["project"]["scripts"]
    assert set(scripts) == {"score-train", "score-transfer", "score-robustness", "score-eval"}
    for target in scripts.values():
        module, function = target.split(":")
        assert callable(getattr(importlib.import_module(module), function))
    packages = PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]
    assert packages == ["score_jax*", "envs*"]  # train.py / transfer.py are not installed


def test_extras_pin_cuda12_to_the_jax_version_and_install_tracking_render_and_paper():
    deps = PYPROJECT["project"]["dependencies"]
    extras = PYPROJECT["project"]["optional-dependencies"]
    jax_pin = next(d for d in deps if d.startswith("jax=="))
    assert extras["cuda12"] == [f"jax[cuda12]=={jax_pin.split('==')[1]}"]
    assert any(d.startswith("tensorboardX") for d in extras["tracking"])
    assert any(d.startswith("wandb") for d in extras["tracking"])
    assert any(d.startswith("imageio-ffmpeg") for d in extras["render"])
    assert any(d.startswith("scikit-learn") for d in extras["paper"])  # Fig. 12's t-SNE


def test_license_changelog_and_readme_notes():
    assert PYPROJECT["project"]["license"] == {"text": "Apache-2.0"}
    text = open(os.path.join(ROOT, "LICENSE")).read()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text
    changelog = open(os.path.join(ROOT, "CHANGELOG.md")).read()
    assert "## [Unreleased]" in changelog and "score-eval" in changelog
    assert 'pip install -e ".[cuda12]"' in README
    assert 'python -c "import jax; print(jax.devices())"' in README
    assert "--track tensorboard" in README and "score-eval --run-dir" in README
    assert "benchmarks/startup.py" in README
    # the README's two set-up commands stay two commands
    quick = README.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"```bash\n(.*?)\n```", quick, re.S) == [
        "python3 -m venv .venv && .venv/bin/pip install -e . && .venv/bin/python train.py",
        "bash scripts/test.sh",
    ]


def test_comparison_budgets_count_environment_steps_whatever_the_action_repeat():
    """compare.py gives every row the same environment steps (simulated days): a greenhouse
    decision held 8 days costs 8; --total-steps still gives decisions."""
    from benchmarks.compare import BUDGETS, CompareArgs, decisions

    gh = CompareArgs(envs=("greenhouse",), env_steps=16_000)
    assert decisions(gh, "greenhouse") == (2_000, 16_000)
    daily = dataclasses.replace(gh, base=TrainConfig(action_repeat=1))
    assert decisions(daily, "greenhouse") == (16_000, 16_000)
    assert decisions(dataclasses.replace(gh, total_steps=100), "greenhouse") == (100, 800)
    paper = CompareArgs(budget="paper")
    assert decisions(paper, "greenhouse") == (125_000, BUDGETS["paper"]["greenhouse"])
    assert decisions(paper, "spider")[1] == BUDGETS["paper"]["spider"]
    with pytest.raises(ValueError, match="less than one decision"):
        decisions(dataclasses.replace(gh, env_steps=4), "greenhouse")


def test_benchmarks_write_to_runs_unless_told_otherwise():
    """No benchmark writes the committed benchmarks/results by default; the README's commands
    that regenerate committed results pass --out benchmarks/results."""
    from benchmarks.compare import CompareArgs

    assert CompareArgs().out == os.path.join(ROOT, "runs", "benchmarks")
    scripts = [
        p for p in glob.glob(os.path.join(ROOT, "benchmarks", "*.py")) if "cpu_devices" not in p
    ]
    assert len(scripts) >= 7
    for path in scripts:
        src = open(path).read()
        assert '"runs"' in src and '"benchmarks"' in src, path
        assert not re.search(r'["\']results["\']\)', src), f"{path} still defaults to results/"
        assert "--out" in src, path
    for line in README.splitlines():
        if "python benchmarks/" in line and "benchmarks/results" in line and "`" in line:
            if "--out" not in line and "writes" not in line:
                pytest.fail(f"README regenerates committed results without --out: {line}")


# --- 7. compilation cache ---------------------------------------------------------------------


@pytest.fixture
def jax_cache_config():
    """Restores the process's compilation-cache settings after a test changes them."""
    names = (
        "jax_compilation_cache_dir",
        "jax_enable_compilation_cache",
        "jax_persistent_cache_min_compile_time_secs",
    )
    saved = {n: getattr(jax.config, n) for n in names}
    yield
    for n, v in saved.items():
        jax.config.update(n, v)


def test_compile_cache_default_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("SCORE_JAX_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert compile_cache.default_cache_dir() == str(tmp_path / "xdg" / "score-jax" / "xla")
    monkeypatch.setenv("SCORE_JAX_CACHE", str(tmp_path / "mine"))
    assert compile_cache.default_cache_dir() == str(tmp_path / "mine" / "xla")


def test_compile_cache_keeps_a_configured_dir_sets_the_default_and_turns_off(
    jax_cache_config, monkeypatch, tmp_path
):
    configured = jax.config.jax_compilation_cache_dir  # the tests' own (conftest.py)
    assert configured
    assert compile_cache.enable_compile_cache() == configured  # respected, not overridden
    assert jax.config.jax_compilation_cache_dir == configured
    # nothing configured: the per-user default, with the minimum compile time
    jax.config.update("jax_compilation_cache_dir", None)
    monkeypatch.setenv("SCORE_JAX_CACHE", str(tmp_path))
    monkeypatch.delenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", raising=False)
    assert compile_cache.enable_compile_cache() == str(tmp_path / "xla")
    assert os.path.isdir(tmp_path / "xla") and compile_cache.cache_status() == str(tmp_path / "xla")
    assert jax.config.jax_persistent_cache_min_compile_time_secs == compile_cache.MIN_COMPILE_SECS
    assert compile_cache.enable_compile_cache(str(tmp_path / "explicit")) == str(
        tmp_path / "explicit"
    )
    assert compile_cache.enable_compile_cache(enabled=False) is None
    assert not jax.config.jax_enable_compilation_cache and compile_cache.cache_status() == "off"


@pytest.mark.parametrize(
    "module, make_args",
    [
        (train_cli, lambda d: TrainConfig(env="no-such-env", describe=True, compile_cache=False)),
        (eval_cli, lambda d: eval_cli.EvalArgs(run_dir=d, compile_cache=False)),
        (robustness_cli, lambda d: robustness_cli.RobustnessArgs(run_dir=d, compile_cache=False)),
        (transfer_cli, lambda d: TransferArgs(checkpoint=d, compile_cache=False)),
    ],
)
def test_every_command_sets_up_the_compile_cache_first(
    module, make_args, monkeypatch, capsys, tmp_path
):
    calls = []
    monkeypatch.setattr(module, "enable_compile_cache", lambda **kw: calls.append(kw))
    assert module.main(make_args(str(tmp_path / "no-run"))) != 0  # an error, after the set-up
    assert calls == [{"enabled": False}]
    assert capsys.readouterr().err.startswith("error: ")


# --- 3. provenance ----------------------------------------------------------------------------


def test_provenance_records_versions_devices_and_the_commit():
    p = provenance()
    for name in ("jax", "jaxlib", "flax", "brax", "mujoco"):
        assert p["packages"][name] == importlib.metadata.version(name)
    assert p["backend"] == jax.default_backend() and p["device_count"] == jax.device_count()
    assert p["device_kinds"] == sorted({d.device_kind for d in jax.devices()})
    assert p["python"] and p["platform"] and p["time_utc"]
    assert set(p["cpu"]["vector_flags"]) <= set(prov_lib.VECTOR_FLAGS)
    head = subprocess.run(
        ["git", "-C", ROOT, "rev-parse", "HEAD"], capture_output=True, text=True, check=False
    )
    if head.returncode == 0:
        assert p["git"]["commit"] == head.stdout.strip()
        assert isinstance(p["git"]["dirty"], bool)
    else:
        assert p["git"] is None


def test_cpu_info_reads_the_model_and_the_vector_flags(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(
        "processor\t: 0\nmodel name\t: AMD EPYC 9B14\nflags\t\t: fpu sse4_2 avx avx2 fma avx512f\n"
        "processor\t: 1\nmodel name\t: AMD EPYC 9B14\nflags\t\t: fpu sse4_2 avx avx2 fma avx512f\n"
    )
    info = prov_lib.cpu_info(str(cpuinfo))
    assert info == {
        "model": "AMD EPYC 9B14",
        "vector_flags": ["sse4_2", "avx", "avx2", "fma", "avx512f"],
    }
    assert prov_lib.cpu_info(str(tmp_path / "absent"))["vector_flags"] == []


def test_git_info_is_none_outside_a_checkout(monkeypatch, tmp_path):
    from score_jax.run import provenance as prov

    git_info.cache_clear()
    monkeypatch.setattr(prov, "_PACKAGE_ROOT", str(tmp_path))
    try:
        assert prov.git_info() is None
        monkeypatch.setattr(prov.shutil, "which", lambda name: None)
        git_info.cache_clear()
        assert prov.git_info() is None
    finally:
        git_info.cache_clear()


# --- 4. header --------------------------------------------------------------------------------


def test_header_has_one_line_per_item_with_the_resolved_numbers(tmp_path):
    cfg = TrainConfig(env="greenhouse", run_dir=str(tmp_path / "r"), track=("tensorboard",))
    env = envs.make("greenhouse")
    lines = header_lines(cfg, resolve(cfg, env), env)
    items = dict(line.split(":", 1) for line in lines)
    assert list(items) == [
        "backend",
        "devices",
        "run dir",
        "env",
        "algo",
        "seed",
        "budget",
        "evaluation",
        "checkpoints",
        "action repeat",
        "updates",
        "tracking",
        "compile cache",
    ]
    assert jax.default_backend() in items["backend"]
    assert f"{jax.device_count()} x" in items["devices"]
    assert str(tmp_path / "r") in items["run dir"]
    assert "144000 decisions = 1152000 env steps" in items["budget"]
    assert "every 16000 decisions (9 evaluations), 10 episodes" in items["evaluation"]
    assert "every 14400 decisions" in items["checkpoints"]
    assert items["action repeat"].strip() == "8 env steps per decision"
    assert items["updates"].strip() == "1 per vectorised step, batch 128, 3-step TD targets"
    assert "csv (" in items["tracking"] and "tensorboard (" in items["tracking"]
    assert items["compile cache"].strip() == jax.config.jax_compilation_cache_dir


def test_announce_refuses_tracking_that_is_not_installed(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a)
    )
    with pytest.raises(ValueError, match=r"--track wandb needs the wandb package.*tracking"):
        announce(TrainConfig(env="probe", track=("wandb",)), log=lambda *a: None)
    with pytest.raises(ValueError, match="unknown writer kind"):
        check_kinds(["mlflow"])


# --- 6. --describe and units ------------------------------------------------------------------


def test_units_take_no_part_in_equality_and_old_metadata_still_loads():
    space = envs.make("greenhouse").space
    assert [s.units for s in space.subspaces] == ["°C", "ppm", "h", "h"]
    saved = space.to_dict()
    assert saved["subspaces"][0]["units"] == "°C"
    assert CompositeSpace.from_dict(saved) == space
    for s in saved["subspaces"]:  # metadata written before sub-spaces had units
        del s["units"]
    old = CompositeSpace.from_dict(saved)
    assert old == space and hash(old) == hash(space) and old.subspaces[0].units == ""
    no_units = CompositeSpace(tuple(dataclasses.replace(s, units="") for s in space.subspaces))
    assert no_units == space


def test_describe_prints_name_kind_dims_range_default_units_and_exits(capsys):
    assert train_cli.main(TrainConfig(env="greenhouse", describe=True)) == 0
    out = capsys.readouterr().out
    assert (
        "--subspaces takes a comma-separated subset of: temperature,co2,lighting,irrigation" in out
    )
    table = out.split("\n\n")[1].splitlines()
    assert table[0].split() == ["name", "kind", "dims", "range", "default", "units"]
    assert table[1].split() == ["temperature", "continuous", "24", "[13,", "25]", "19", "°C"]
    assert table[3].split() == ["lighting", "discrete(24)", "2", "[0,", "23]", "6,", "18", "h"]
    assert "action repeat 8" in out and "budget 144000 decisions" in out
    assert train_cli.main(TrainConfig(env="spider", describe=True)) == 0
    assert "leg_mid_left" in capsys.readouterr().out and "normalised torque" in (
        envs.make("spider").space.describe()
    )


def test_test_modules_holding_a_slow_test_are_scheduled_first():
    """scripts/test.sh keeps the order tests/conftest.py gives (--no-loadscope-reorder): modules
    with a slow test first, in collection order, then the others by number of tests."""
    from tests.conftest import pytest_collection_modifyitems

    class Item:
        def __init__(self, nodeid, slow=False):
            self.nodeid, self.slow = nodeid, slow

        def get_closest_marker(self, name):
            return name == "slow" and self.slow or None

    items = [
        Item("tests/test_a.py::x"),
        Item("tests/test_b.py::x"),
        Item("tests/test_b.py::y"),
        Item("tests/test_c.py::x", slow=True),
        Item("tests/test_d.py::x"),
        Item("tests/test_d.py::y", slow=True),
        Item("tests/test_e.py::x"),
        Item("tests/test_e.py::y"),
        Item("tests/test_e.py::z"),
    ]
    pytest_collection_modifyitems(None, items)
    modules = list(dict.fromkeys(i.nodeid.split("::")[0][len("tests/test_") :] for i in items))
    assert modules == ["c.py", "d.py", "e.py", "b.py", "a.py"]
    assert [i.nodeid for i in items[1:3]] == ["tests/test_d.py::x", "tests/test_d.py::y"]
    assert "--no-loadscope-reorder" in open(os.path.join(ROOT, "scripts", "test.sh")).read()
