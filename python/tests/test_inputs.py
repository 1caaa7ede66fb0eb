"""Every Python entry point given wrong types, shapes, non-finite or empty values raises
skyloop.InputError with one line: never a crash, never pybind11's multi-line TypeError."""
import threading

import numpy as np
import pytest

import skyloop as sl

CFG = {"env.oracle": "zf"}


def cluster():
    return sl.Cluster(np.ones((3, 4), complex), 1.0, 1e-12)


def env():
    return sl.VecEnv(CFG, 2, 0)


CASES = [
    # configuration
    ("config path", lambda: sl.config(3)),
    ("config overrides list", lambda: sl.config(overrides=["channel.p_max_dbm=40"])),
    ("config key smuggles a value", lambda: sl.config(overrides={"channel.p_max_dbm=50 #": 40})),
    ("config value nan", lambda: sl.config(overrides={"channel.p_max_dbm": float("nan")})),
    ("config value inf", lambda: sl.config(overrides={"channel.noise_dbm": float("inf")})),
    ("config value object", lambda: sl.config(overrides={"channel.p_max_dbm": object()})),
    ("config users range", lambda: sl.config(overrides={"env.users_max": 100000})),
    ("config getitem smuggles", lambda: sl.config()["run.seed=1 #"]),
    ("config getitem type", lambda: sl.config()[3]),
    ("Config ctor types", lambda: sl.Config(3, 4)),
    # clusters and rates
    ("cluster L = 0", lambda: sl.Cluster(np.ones((3, 0), complex), 1, 1e-12)),
    ("cluster K = 0", lambda: sl.Cluster(np.ones((0, 4), complex), 1, 1e-12)),
    ("cluster p_max inf", lambda: sl.Cluster(np.ones((3, 4), complex), float("inf"), 1e-12)),
    ("cluster noise inf", lambda: sl.Cluster(np.ones((3, 4), complex), 1.0, float("inf"))),
    ("cluster p_max nan", lambda: sl.Cluster(np.ones((3, 4), complex), float("nan"), 1e-12)),
    ("cluster G nan", lambda: sl.Cluster(np.full((3, 4), np.nan, complex), 1.0, 1e-12)),
    ("cluster G 1-d", lambda: sl.Cluster(np.ones(4, complex), 1.0, 1e-12)),
    ("cluster G text", lambda: sl.Cluster("G", 1.0, 1e-12)),
    ("cluster users count", lambda: sl.Cluster(np.ones((3, 4), complex), 1.0, 1e-12, 0, [1])),
    ("sum_rate W shape", lambda: sl.sum_rate(cluster(), np.ones((2, 2), complex))),
    ("sum_rate W text", lambda: sl.sum_rate(cluster(), "W")),
    ("sum_rate cluster type", lambda: sl.sum_rate(3, np.ones((4, 3), complex))),
    ("beamformer spec type", lambda: sl.beamformer(3)),
    ("beamformer unknown", lambda: sl.beamformer("nope")),
    ("design cluster type", lambda: sl.beamformer("zf").design("c")),
    ("system model type", lambda: sl.SystemModel(3)),
    ("random snapshot types", lambda: sl.SystemModel(sl.config()).random_snapshot("a", 3, 1)),
    # environment
    ("num_envs fraction", lambda: sl.VecEnv(CFG, 2.7, 0)),
    ("num_envs text", lambda: sl.VecEnv(CFG, "3", 0)),
    ("num_envs bool", lambda: sl.VecEnv(CFG, True, 0)),
    ("num_envs zero", lambda: sl.VecEnv(CFG, 0, 0)),
    ("num_envs huge", lambda: sl.VecEnv(CFG, 10**7, 0)),
    ("seed negative", lambda: sl.VecEnv(CFG, 1, -1)),
    ("oracle type", lambda: sl.VecEnv(CFG, 1, 0, oracle=3)),
    ("step float actions", lambda: env().step(np.zeros((2, 3)))),
    ("step shape", lambda: env().step(np.zeros((3, 2), np.int64))),
    ("step empty", lambda: env().step([])),
    ("step out of range", lambda: env().step(np.full((2, 3), 7))),
    ("step ragged", lambda: env().step([[0, 1], [2]])),
    ("step text", lambda: env().step("up")),
    ("reset seed fraction", lambda: env().reset(seed=1.5)),
    ("users index", lambda: env().users(5)),
    ("field unknown", lambda: env().field(np.zeros((2, 3, 11)), "obs", "x")),
    # planners and layouts
    ("plan planner type", lambda: sl.plan(CFG, planner=3)),
    ("plan users nan", lambda: sl.plan(CFG, planner="greedy", users=[[np.nan, 10.0]])),
    ("plan users empty", lambda: sl.plan(CFG, planner="greedy", users=np.zeros((0, 2)))),
    ("plan users shape", lambda: sl.plan(CFG, planner="greedy", users=[1, 2, 3])),
    ("plan users text", lambda: sl.plan(CFG, planner="greedy", users="here")),
    ("plan users outside", lambda: sl.plan(CFG, planner="greedy", users=[[500.0, 10.0]])),
    ("plan seed negative", lambda: sl.plan(CFG, planner="greedy", users_seed=-3)),
    ("plan unknown", lambda: sl.plan(CFG, planner="nope")),
    ("layouts zero", lambda: sl.evaluate_layouts(CFG, planners=["random"], layouts=0)),
    ("layouts repeated planner", lambda: sl.evaluate_layouts(CFG, planners=["random", "random"], layouts=1)),
    ("layouts planners type", lambda: sl.evaluate_layouts(CFG, planners=3, layouts=1)),
    ("layouts unsafe type", lambda: sl.evaluate_layouts(CFG, planners=["random"], layouts=1, unsafe="yes")),
    ("layouts rollout type", lambda: sl.evaluate_layouts(CFG, planners=["random"], layouts=1, rollout=1)),
    ("layouts split", lambda: sl.evaluate_layouts(CFG, planners=["random"], layouts=1, split="nope")),
    ("derive_seed negative", lambda: sl.derive_seed(-1, 0)),
]


# evaluate_layouts needs the learners (a LibTorch build); the sanitizer build has none.
CASES = [c for c in CASES if sl._skyloop.HAS_TORCH or not c[0].startswith("layouts")]


@pytest.mark.parametrize("name,call", CASES, ids=[c[0] for c in CASES])
def test_bad_input_raises_one_line_input_error(name, call):
    with pytest.raises(sl.InputError) as e:
        call()
    text = str(e.value)
    assert text and "\n" not in text, f"{name}: not one line: {text!r}"


@pytest.mark.skipif(not sl._skyloop.HAS_TORCH, reason="evaluate_layouts needs a LibTorch build")
def test_a_single_planner_name_is_one_name():
    from conftest import SQUARE  # the optimum each layout row carries, in a fraction of a second
    out = sl.evaluate_layouts({**SQUARE, "scenario.users": 6}, planners="random", layouts=1)
    assert [r["planner"] for r in out["summary"]] == ["random", "optimal"] or \
        sorted(r["planner"] for r in out["summary"]) == ["optimal", "random"]
    assert all(r["layouts"] == 1 for r in out["summary"])


def test_a_failed_step_corrupts_nothing():
    e = env()
    o = e.reset()
    with pytest.raises(sl.InputError):
        e.step(np.full((2, 3), 9))
    r = e.step(np.full((2, 3), sl.ACTIONS.index("STAY")))
    assert r.obs.shape == o.obs.shape and np.all(r.info["T"] == 2)


def test_users_file_gives_k_everywhere(tmp_path):
    f = tmp_path / "users.toml"
    f.write_text("users = [[10.0, 10.0], [150.0, 120.0]]\n")
    cfg = sl.config(overrides={"env.users_file": str(f), "scenario.users": 7})
    assert cfg["scenario.users"] == 2
    assert "users = 2" in cfg.toml()


def test_cli_out_with_a_trailing_slash_on_a_file(skyloop_bin, tmp_path):
    """`--out trail/` where trail is a file: one line, exit 2, nothing created (it used to leave an
    empty directory and say only "Not a directory")."""
    from conftest import run_cli
    trail = tmp_path / "trail"
    trail.write_text("keep me\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    r = run_cli("plan", "--planner", "random", "--set", "env.oracle=zf", "--out", str(trail) + "/")
    assert r.returncode == 2 and "exists and is not a directory" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before and trail.read_text() == "keep me\n"


def test_cli_header_and_config_state_the_users_files_k(skyloop_bin, tmp_path):
    from conftest import run_cli
    f = tmp_path / "users.toml"
    f.write_text("users = [[10.0, 10.0], [150.0, 120.0]]\n")
    r = run_cli("plan", "--planner", "greedy", "--set", "env.oracle=zf", "--set", f"env.users_file={f}",
                "--set", "scenario.users=7", "--out", str(tmp_path / "p"))
    assert r.returncode == 0, r.stderr
    assert "K = 2 users" in r.stdout
    assert "users = 2 " in (tmp_path / "p" / "config.toml").read_text()
