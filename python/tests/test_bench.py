"""skyloop.bench: any policy scored on a task's test layouts by the same code as `skyloop bench run`."""
import csv
import io
import json
import os
import re

import numpy as np
import pytest

import skyloop as sl

bench = pytest.importorskip("skyloop.bench")
if not getattr(sl._skyloop, "HAS_TORCH", False):
    pytest.skip("the benchmark needs the LibTorch build", allow_module_level=True)

from conftest import run_cli  # noqa: E402


def plan_replay(task):
    """Each test layout's Greedy moves from sl.plan on that layout's users, and its objective."""
    env = sl.VecEnv(task.config, len(task.users_seeds), layouts=task.users_seeds)
    plans = [sl.plan(task.config, "greedy", users=env.users(i)) for i in range(env.num_envs)]
    env.close()
    return plans


def test_a_python_policy_scores_as_its_moves_flown_through_plan():
    # A policy in plain Python that flies, layout by layout, the moves sl.plan's Greedy flew on the
    # same users: bench.evaluate must give sl.plan's objectives, and `bench run`'s Greedy rows.
    task = bench.task("paper-v1")
    plans = plan_replay(task)
    slot = {"t": 0}

    def replay(batch):
        t = slot["t"]
        slot["t"] += 1
        hover = batch["spec"]["hover"]
        out = np.full(batch["obs"].shape[:2], hover, dtype=np.int64)
        for i, p in enumerate(plans):
            if t < len(p["actions"]):
                out[i] = p["actions"][t]
        return out

    result = bench.evaluate(task, {1: replay}, label="replay", steps=task.protocol["budget_steps"])
    assert len(result.rows) == len(task.users_seeds)
    for row, p in zip(result.rows, plans):
        assert row["objective"] == pytest.approx(p["objective"], rel=1e-12)
        assert row["fraction"] == pytest.approx(p["objective"] / row["reference_objective"], rel=1e-12)
        assert row["complete"] == (p["success"] and p["collisions"] == 0 and p["boundary"] == 0)
        assert row["protocol"] == "ok"
    cpp = bench.evaluate(task, "greedy")
    greedy = [r for r in cpp.rows if r["seed"] == 1]
    assert [r["objective"] for r in greedy] == pytest.approx([r["objective"] for r in result.rows], rel=1e-12)
    s = result.summary[0]
    assert s["seeds"] == 1 and s["layouts"] == len(task.users_seeds)
    assert "1 seeds of the protocol's 5" in s["protocol"]  # one seed is not the protocol, and says so


def test_a_masked_policy_in_plain_python_is_scored_and_labelled():
    # The first allowed move of every UAV (its action mask), a policy no one trained: scored on
    # every layout, each against the shipped optimum; no budget stated, so labelled off-protocol.
    task = bench.task("paper-v1")

    def first_allowed(batch):
        return np.argmax(batch["action_mask"], axis=-1)

    result = bench.evaluate(task, {s: first_allowed for s in range(1, 6)}, label="first")
    assert len(result.rows) == 5 * len(task.users_seeds)
    assert all(0 <= r["fraction"] <= 1 + 1e-9 for r in result.rows)
    s = result.summary[0]
    assert s["seeds"] == 5 and s["iqm_ci_low"] == s["iqm_ci_high"]  # a deterministic policy: no spread over seeds
    assert s["protocol"] == "training budget not stated"
    rows = list(csv.DictReader(io.StringIO(result.files["rows.csv"])))
    assert {r["protocol"] for r in rows} == {"training budget not stated"}
    doc = json.loads(result.files["marl_eval.json"])
    assert len(doc["skyloop"]["paper-v1"]["first"]["seed_3"]["absolute_metrics"]["fraction_of_reference"]) == len(task.users_seeds)


def test_the_iqm_is_scipys_trimmed_mean():
    assert bench.interquartile_mean([8, 1, 7, 2, 6, 3, 5, 4]) == 4.5
    try:
        from scipy.stats import trim_mean
    except ImportError:
        return
    x = np.random.default_rng(3).normal(size=37)
    assert bench.interquartile_mean(x) == pytest.approx(trim_mean(x, 0.25), rel=1e-12)


def test_bad_policies_and_tasks_are_one_line():
    with pytest.raises(sl.InputError, match="allowed .*paper-v1"):
        bench.task("nope")
    with pytest.raises(sl.InputError, match="not callable"):
        bench.evaluate("paper-v1", {1: 3})
    with pytest.raises(sl.InputError, match="wrong type"):
        bench.evaluate("paper-v1", 3.5)
    with pytest.raises(sl.InputError, match="layouts"):
        sl.VecEnv(bench.task("paper-v1").config, 3, layouts=[1, 2])


def test_the_command_line_lists_runs_and_checks(tmp_path):
    r = run_cli("bench", "list")
    assert r.returncode == 0, r.stderr
    for t in ("paper-v1", "uma-rician-v1", "shared-wmmse-v2", "energy-headings-v1", "continuous-v1", "fleet16-v1"):
        assert t in r.stdout
    assert re.search(r"^shared-wmmse-v1 +withdrawn, successor shared-wmmse-v2", r.stdout, re.M), r.stdout
    r = run_cli("bench", "reference", "shared-wmmse-v1")
    assert r.returncode == 2 and "was withdrawn" in r.stderr and "successor: shared-wmmse-v2" in r.stderr
    out = tmp_path / "b"
    r = run_cli("bench", "run", "paper-v1", "--planner", "greedy", "--seeds", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    for f in ("rows.csv", "summary.csv", "profile.csv", "marl_eval.json", "config.toml"):
        assert (out / f).exists(), f
    rows = list(csv.DictReader(open(out / "rows.csv")))
    assert len(rows) == 20 and {r["seed"] for r in rows} == {"1"}
    profile = list(csv.DictReader(open(out / "profile.csv")))
    at0 = [p for p in profile if float(p["tau"]) == 0.0]
    assert at0 and float(at0[0]["fraction_of_runs"]) == 1.0  # every run reaches 0% of the optimum
    r = run_cli("bench", "run", "paper-v9", "--planner", "greedy")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "allowed" in r.stderr
    r = run_cli("bench", "run", "paper-v1", "--planner", "optimal")
    assert r.returncode == 2 and "optimal" in r.stderr
    for bad, field in ((["--jobs", "0"], "--jobs"), (["--steps", "0"], "--steps"), (["--seeds", "x"], "--seeds"),
                       (["--learners", "mappo,nosuch"], "--learners = 'nosuch' is unknown")):
        r = run_cli("bench", "baselines", "paper-v1", *bad, "--out", str(tmp_path / "never"))
        assert r.returncode == 2 and field in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not (tmp_path / "never").exists()  # refused before anything is written
    r = run_cli("bench", "reference", "paper-v1", "--sample", "1")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "reproduced" in r.stdout


def test_a_tampered_reference_is_refused(tmp_path):
    import shutil
    src = bench.task("paper-v1").dir
    dst = tmp_path / "paper-v1"
    shutil.copytree(src, dst)
    text = (dst / "reference.csv").read_text().splitlines()
    parts = text[1].split(",")
    parts[6] = str(float(parts[6]) * 0.9)  # the first layout's optimum, 10% lower
    text[1] = ",".join(parts)
    (dst / "reference.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(sl.InputError, match="checksum"):
        bench.task(str(dst))
    r = run_cli("bench", "run", str(dst), "--planner", "greedy")
    assert r.returncode == 2 and "checksum" in r.stderr


def test_baselines_train_score_and_label_a_short_budget(tmp_path):
    # The baselines command on a tiny budget: the planners, and MAPPO trained for 2048 steps on one
    # seed, scored and labelled off the protocol (its budget, its single seed) in every row.
    out = tmp_path / "board"
    r = run_cli("bench", "baselines", "paper-v1", "--learners", "mappo", "--seeds", "1", "--steps", "2048",
                "--out", str(out), "--set", "marl.envs=2", "--set", "marl.rollout=64")
    assert r.returncode == 2 and "--set" in r.stderr  # the task's configuration is frozen: no overrides
    r = run_cli("bench", "baselines", "paper-v1", "--learners", "mappo", "--seeds", "1", "--steps", "2048", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    summary = {s["policy"]: s for s in csv.DictReader(open(out / "summary.csv"))}
    assert set(summary) == {"random", "greedy", "seqgreedy", "rollout", "mappo"}
    assert "trained 2048 steps, the budget is 2000000" in summary["mappo"]["protocol"]
    assert "1 seeds of the protocol's 5" in summary["mappo"]["protocol"]
    rows = [r for r in csv.DictReader(open(out / "rows.csv")) if r["policy"] == "mappo"]
    assert len(rows) == 20 and all("trained 2048 steps" in r["protocol"] for r in rows)
    assert (out / "train" / "mappo-s1" / "policy.pt").exists()
    # Two trainings at a time (child processes on a share of the threads each) give the same
    # numbers; a rerun finds every run trained and only scores them.
    par = tmp_path / "parallel"
    r = run_cli("bench", "baselines", "paper-v1", "--learners", "mappo", "--seeds", "1,2", "--steps", "2048", "--jobs", "2",
                "--out", str(par))
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr.count("training mappo seed") == 2 and (par / "train" / "mappo-s2.log").exists()
    assert "(1/2 runs)" in r.stderr and "(2/2 runs)" in r.stderr, r.stderr  # progress counts the ended trainings
    seed1 = [r for r in csv.DictReader(open(par / "rows.csv")) if r["policy"] == "mappo" and r["seed"] == "1"]
    assert [(r["layout"], r["objective"]) for r in seed1] == [(r["layout"], r["objective"]) for r in rows]
    r = run_cli("bench", "baselines", "paper-v1", "--learners", "mappo", "--seeds", "1,2", "--steps", "2048", "--jobs", "2",
                "--out", str(par))
    assert r.returncode == 0 and "training" not in r.stderr, r.stderr[-2000:]
    # trainings.csv: one row per training the command ran (the rerun trained none, so added none),
    # with its time, how many ran at a time, and the machine, as the leaderboard page states them.
    made = list(csv.DictReader(open(par / "trainings.csv")))
    assert sorted((m["algo"], m["seed"], m["steps"], m["resumed"], m["jobs"]) for m in made) == \
        [("mappo", "1", "2048", "0", "2"), ("mappo", "2", "2048", "0", "2")]
    assert all(float(m["seconds"]) > 0 and "-core " in m["machine"] and m["task"] == "paper-v1" for m in made)
    # --time-limit: a training starts only while 1.3 x the board's longest recorded one of the same
    # learner and budget fits in what is left; a third seed cannot fit in 0.1 s, so nothing is
    # trained or scored (the board's files stay as they were) and the command exits 75 saying so.
    rows_before = (par / "rows.csv").read_text()
    r = run_cli("bench", "baselines", "paper-v1", "--learners", "mappo", "--seeds", "1,2,3", "--steps", "2048", "--jobs", "2",
                "--time-limit", "0.1s", "--out", str(par))
    assert r.returncode == 75, r.stderr[-2000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("time limit: stopped after") and "1 of 1 trainings left (mappo seed 3" in last, last
    assert not (par / "train" / "mappo-s3").exists() and (par / "rows.csv").read_text() == rows_before
    assert len(list(csv.DictReader(open(par / "trainings.csv")))) == 2
    r = run_cli("bench", "baselines", "paper-v1", "--time-limit", "90", "--out", str(par))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--time-limit = '90'" in r.stderr, r.stderr


def test_baselines_say_which_learner_cannot_run_a_task(tmp_path):
    # uma-rician-v1 trains its UAVs one after another (marl.sequential), which VDN and QMIX cannot:
    # each is a line of not_run.txt saying why, and nothing is trained for it.
    out = tmp_path / "board"
    r = run_cli("bench", "baselines", "uma-rician-v1", "--learners", "vdn", "--seeds", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    assert "vdn: not run (marl.sequential = true" in (out / "not_run.txt").read_text()
    assert not (out / "train").exists()
    assert {s["policy"] for s in csv.DictReader(open(out / "summary.csv"))} == {"random", "greedy", "seqgreedy", "rollout"}
