"""benchmarks/paper.py end to end at a tiny budget on the probe: the comparison with transfer,
the robustness sweeps, the figures, the tables and the claims reach results.md. (SCORE alone:
the figures' functions, Figs. 11 and 12 included, have their own tests in test_paper_figures.)"""

import dataclasses
import json
import os
import shutil

import pytest

from benchmarks import paper
from score_jax.run.config import TrainConfig
from tests.tiny import TINY_OFF_POLICY, TINY_SCORE

pytestmark = pytest.mark.slow  # scheduled first (conftest)


def test_quick_pipeline_writes_tables_figures_and_claims(tmp_path, capfd):
    out, work = tmp_path / "out", tmp_path / "work"
    args = paper.PaperArgs(
        quick=True,
        envs=("probe",),
        algos=("score",),
        ablations="none",
        seeds=2,
        env_steps=400,
        out=str(out),
        work_dir=str(work),
        base=TrainConfig(
            quiet=True,
            robustness_seeds=0,
            checkpoint_every=200,
            off_policy=TINY_OFF_POLICY,
            score=TINY_SCORE,
        ),
    )
    assert paper.main(args) == 0
    # each run's evaluations are printed under its name as they come (a run takes minutes)
    printed = capfd.readouterr().out  # fd level: side by side, the runs print from children
    assert "    SCORE full: " in printed and "evaluation mean" in printed, printed
    md = (out / "results.md").read_text()
    for text in (
        "### Claims",
        "Table 2 (ablations)",
        "Table 3 (transfer",
        "| ASRL+AL+HN (SCORE) |",
    ):
        assert text in md, text
    assert "**" in md.split("### Claims")[1].split("### Tables")[0]  # a verdict per claim
    results = json.load(open(out / "results" / "results.json"))
    probe = results[0]
    claims = {c["claim"]: c for c in probe["priors"]["on"]["claims"]}
    assert set(claims) == {"effectiveness", "robustness", "transfer", "ablation"}
    assert claims["effectiveness"]["verdict"] == "not measured"  # no baseline was run
    assert claims["transfer"]["verdict"] == "not measured"
    assert set(probe["priors"]["on"]["robustness"]) == {"SCORE"}
    drawn = set(probe["figures"])
    assert drawn == {"P-a", "P-b", "P-r"}, probe["notes"]  # 10: greenhouse; 11, 12: ablations
    for name in drawn:
        assert os.path.getsize(out / "results" / probe["figures"][name]) > 10_000
        assert f"results/{probe['figures'][name]}" in md
    # every run was kept: a second invocation trains nothing (a killed one resumes the same way)
    runs = sorted(p for p in work.rglob("result.json"))
    stamps = [p.stat().st_mtime for p in runs]
    assert len(runs) == 3  # SCORE on the full space, its subset run and the transfer from it
    assert paper.main(args) == 0
    assert [p.stat().st_mtime for p in runs] == stamps
    # a work directory moved elsewhere without its checkpoints (as the committed CPU-scale runs
    # are kept) is still reused: where a run lives is not part of its settings
    moved = tmp_path / "moved"
    shutil.move(str(work), str(moved))
    for heavy in [*moved.rglob("checkpoints"), *moved.rglob("best")]:
        shutil.rmtree(heavy)
    kept = sorted(moved.rglob("result.json"))
    stamps = [p.stat().st_mtime for p in kept]
    assert paper.main(dataclasses.replace(args, work_dir=str(moved))) == 0
    assert [p.stat().st_mtime for p in kept] == stamps
    assert not list(moved.rglob("checkpoints"))
    # a run kept without its sweep and its checkpoints is trained again, then swept at once; the
    # same settings and seeds give the same result
    full = next(p.parent for p in kept if p.parent.parent.name == "score")
    before = json.load(open(full / "result.json"))
    os.remove(full / "robustness.json")
    assert paper.main(dataclasses.replace(args, work_dir=str(moved))) == 0
    assert (full / "robustness.json").exists() and (full / "checkpoints").is_dir()
    assert json.load(open(full / "result.json"))["returns"] == before["returns"]
    # --no-train writes the page from what is there and names what is not (a page gathered over
    # several sessions): ISAC's rows are listed as not run, and nothing is trained
    partial = dataclasses.replace(args, work_dir=str(moved), algos=("score", "isac"), no_train=True)
    assert paper.main(partial) == 0
    md = (out / "results.md").read_text()
    assert "**Partial:**" in md and "ISAC full" in md and "ISAC transfer" in md, md
    assert "- Runs trained at: `" in md
    assert sorted(moved.rglob("result.json")) == kept
    # --only trains the runs it names (each swept at once) and writes the same partial page
    with pytest.raises(SystemExit, match="the runs are: .*ISAC full"):
        paper.main(dataclasses.replace(partial, no_train=False, only=("ISAC ful",)))
    assert paper.main(dataclasses.replace(partial, no_train=False, only=("ISAC full",))) == 0
    isac = [p for p in moved.rglob("result.json") if p not in kept]
    assert [p.parent.parent.name for p in isac] == ["isac"]
    assert (isac[0].parent / "robustness.json").exists()
    partial_line = next(
        x for x in (out / "results.md").read_text().split("\n") if "**Partial:**" in x
    )
    assert "ISAC transfer" in partial_line and "ISAC full" not in partial_line, partial_line


def test_quick_base_caps_asrl_and_checkpoints_unless_base_sets_them():
    quick = paper.quick_base(paper.PaperArgs(quick=True))
    assert quick.score.asrl_steps == paper.QUICK_ASRL_STEPS
    assert quick.checkpoint_every == paper.QUICK_CHECKPOINT_EVERY
    own = paper.quick_base(paper.PaperArgs(quick=True, base=TrainConfig(checkpoint_every=7)))
    assert own.checkpoint_every == 7
    assert paper.quick_base(paper.PaperArgs()) == paper.PaperArgs().base


def test_page_names_the_commit_it_was_given():
    """main() takes the checkout's state before anything is written, so a page written into the
    repository (--out docs) is not called dirty by its own figures; page() prints what it got."""
    args = paper.PaperArgs(quick=True, envs=("probe",))
    p = paper.plan(args)
    md = paper.page(args, p, [], 60.0, {"commit": "abc123", "dirty": False})
    assert "- Commit: `abc123`\n" in md
    md = paper.page(args, p, [], 60.0, {"commit": "abc123", "dirty": True})
    assert "- Commit: `abc123` (dirty)\n" in md


def test_a_figure_from_policies_is_kept_only_while_its_runs_are_unchanged(tmp_path):
    """Figs. 10 and 12 read trained policies, which the committed store does not keep: a later
    page keeps the figure drawn from the same runs, and not once a run has changed."""
    runs = []
    for name in ("a", "b"):
        d = tmp_path / name
        d.mkdir()
        json.dump(
            {"key": {"algo": name}, "returns": [1.0, 2.0], "wall_s": 3.0},
            open(d / "result.json", "w"),
        )
        runs.append(str(d))
    fig = tmp_path / "fig10_greenhouse.png"
    assert paper.kept_figure(str(fig), runs) is None  # never drawn
    fig.write_bytes(b"png")
    assert paper.kept_figure(str(fig), runs) is None  # drawn, but from what is not recorded
    paper.record_figure_inputs(str(fig), runs)
    assert paper.kept_figure(str(fig), runs).startswith("on ")
    # a retraining that reproduces the returns (wall time aside) leaves the figure standing
    saved = json.load(open(tmp_path / "a" / "result.json"))
    json.dump({**saved, "wall_s": 9.0}, open(tmp_path / "a" / "result.json", "w"))
    assert paper.kept_figure(str(fig), runs) is not None
    json.dump({**saved, "returns": [1.0, 2.5]}, open(tmp_path / "a" / "result.json", "w"))
    assert paper.kept_figure(str(fig), runs) is None
    os.remove(tmp_path / "b" / "result.json")
    assert paper.kept_figure(str(fig), runs) is None
