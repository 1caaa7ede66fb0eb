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
    # sizes bounded before anything is allocated; every number finite (each case once took 42 s and
    # 15.8 GB, returned a broken snapshot, or returned NaN)
    ("random snapshot users huge", lambda: sl.SystemModel(sl.config()).random_snapshot(3, 10**9, seed=1)),
    ("random snapshot users negative", lambda: sl.SystemModel(sl.config()).random_snapshot(3, -1, seed=1)),
    ("random snapshot uavs zero", lambda: sl.SystemModel(sl.config()).random_snapshot(0, 10, seed=1)),
    ("random snapshot uavs 65", lambda: sl.SystemModel(sl.config()).random_snapshot(65, 10, seed=1)),
    ("link nan", lambda: sl.SystemModel(sl.config()).link(np.nan, 0.0, 10.0, 10.0)),
    ("link inf", lambda: sl.SystemModel(sl.config()).link(0.0, 0.0, np.inf, 10.0)),
    ("link altitude underground", lambda: sl.SystemModel(sl.config()).link(0.0, 0.0, 10.0, 10.0, uz=-5.0)),
    ("snapshot altitude nan", lambda: sl.SystemModel(sl.config()).snapshot(sl.config(), np.array([[0.0, 0.0, np.nan]]),
                                                                          np.array([[10.0, 10.0]]))),
    ("sum_rate W inf", lambda: sl.sum_rate(cluster(), np.full((4, 3), np.inf))),
    ("sum_rate W nan", lambda: sl.sum_rate(cluster(), np.full((4, 3), np.nan, complex))),
    ("plan users beyond the bound", lambda: sl.plan(CFG, planner="random", users=np.full((5000, 2), 10.0))),
    ("seed beyond the CLI's range", lambda: sl.VecEnv(CFG, 1, 2**62 + 1)),
    ("plan seed beyond the CLI's range", lambda: sl.plan(CFG, planner="random", users_seed=2**64 - 1)),
    ("config user 1 mm below the UAV", lambda: sl.config(overrides={"scenario.user_height_m": 99.999})),
    ("config rician K min above max", lambda: sl.config(overrides={"channel.rician_k_min_db": 20, "channel.rician_k_max_db": 10})),
    ("config energy objective without energy", lambda: sl.config(overrides={"env.objective": "energy-efficiency",
                                                                             "energy.model": "none"})),
    # the field: validated before it is used
    ("field array name None", lambda: env().field(np.zeros((2, 3, 11)), None, "x")),
    ("field array text", lambda: env().field("obs", "obs", "own_position")),
    ("step nan action", lambda: env().step(np.full((2, 3), np.nan))),
    ("step 4.9", lambda: env().step(np.full((2, 3), 4.9))),
    ("step None", lambda: env().step(None)),
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


def test_nan_and_fractional_actions_are_named_as_given():
    """A NaN action used to be reported as -9223372036854775808 and 4.9 stepped as 4."""
    for bad, shown in ((np.nan, "nan"), (4.9, "4.9")):
        a = np.zeros((2, 3))
        a[1, 2] = bad
        with pytest.raises(sl.InputError) as e:
            env().step(a)
        assert "actions[1, 2]" in str(e.value) and shown in str(e.value), str(e.value)


def test_adapters_validate_before_converting():
    """Each adapter call below used to raise a raw TypeError / ValueError / IndexError, or to
    truncate (seed 2.7 -> 2, action 4.9 -> 4)."""
    from skyloop.adapters import GymVectorEnv, ParallelEnv, SmacEnv
    bad = [
        lambda: ParallelEnv(CFG, seed=None),
        lambda: ParallelEnv(CFG, seed="abc"),
        lambda: ParallelEnv(CFG, seed=2.7),
    ]
    p = ParallelEnv(CFG, seed=1)
    p.reset()
    for v in ("abc", None, np.nan, 4.9, 7):
        bad.append(lambda v=v: p.step({a: v for a in p.possible_agents}))
    smac = SmacEnv(CFG, seed=1)
    bad += [lambda: smac.step(["a", "b", "c"]), lambda: smac.get_obs_agent(7), lambda: smac.get_obs_agent("0"),
            lambda: smac.step([0.5, 1, 2])]
    cont = {**CFG, "trajectory.mobility": "continuous"}
    g = GymVectorEnv(cont, num_envs=2, seed=1)
    g.reset()
    bad += [lambda: g.step(np.zeros((2, 5))), lambda: g.step(np.full((2, 6), np.nan))]
    for call in bad:
        with pytest.raises(sl.InputError) as e:
            call()
        assert "\n" not in str(e.value)
    # the same checks let good values through unchanged
    assert p.step({a: np.int64(4) for a in p.possible_agents})[0]
    assert g.step(np.zeros((2, 6)))[0].shape[0] == 2


def test_closed_environments_refuse_every_call():
    from skyloop.adapters import GymVectorEnv
    g = GymVectorEnv(CFG, num_envs=2, seed=1)
    g.reset()
    g.close()
    for call in (lambda: g.step(np.zeros((2, 3), np.int64)), lambda: g.reset()):
        with pytest.raises(sl.InputError):
            call()
    e = env()
    e.close()
    e.close()  # closing twice is allowed
    with pytest.raises(sl.InputError) as err:
        e.reset()
    assert "closed" in str(err.value)


def test_vecenv_and_config_pickle_as_their_arguments():
    import pickle
    cfg = sl.config(overrides=CFG)
    assert pickle.loads(pickle.dumps(cfg)).toml() == cfg.toml()
    e = sl.VecEnv(cfg, 2, 5)
    first = e.reset().obs
    e.step(np.full((2, 3), sl.ACTIONS.index("UP")))
    again = pickle.loads(pickle.dumps(e))
    assert again.num_envs == 2 and again.config.toml() == cfg.toml()
    np.testing.assert_array_equal(again.reset().obs, first)  # made afresh: its first episode's start


def test_a_fleet_home_over_its_budget_terminates_and_is_not_truncated():
    """Every UAV home early but over energy.budget_j: the episode ended because the UAVs arrived
    (terminated), not at T_max (truncated); success says the mission failed. Each UAV of the
    paper's layout flies straight home (12, 16 and 12 moves: home at slot 17 of 24)."""
    cfg = {**CFG, "energy.budget_j": 1000, "marl.action_mask": False, "marl.shield": False}
    e = sl.VecEnv(cfg, 1, 0)
    e.reset()
    up, down, left, right, stay = (sl.ACTIONS.index(a) for a in ("UP", "DOWN", "LEFT", "RIGHT", "STAY"))
    paths = [[right] * 8 + [up] * 4, [right] * 8 + [down] * 8, [left] * 8 + [down] * 4]
    for t in range(16):
        r = e.step(np.array([[p[t] if t < len(p) else stay for p in paths]], np.int64))
        if t < 15:
            assert not (r.terminated[0] or r.truncated[0])
    assert int(r.info["T"][0]) == 17
    assert bool(r.terminated[0]) and not bool(r.truncated[0])
    assert not bool(r.info["success"][0])


@pytest.mark.skipif(not sl._skyloop.HAS_TORCH, reason="learned beamformers need a LibTorch build")
def test_a_shipped_model_is_found_from_any_directory(tmp_path, monkeypatch):
    """`gnn=models/gnn_structured` (the spec the docs use) names the shipped model when no such
    path exists where the user stands; a path that is neither still fails in one line."""
    monkeypatch.chdir(tmp_path)
    cfg = sl.config()
    snap = sl.SystemModel(cfg).random_snapshot(3, 12, seed=1)
    shipped = sl.beamformer("gnn=models/gnn_structured", cfg)
    c = sl.SystemModel(cfg).clusters(snap)[0]
    assert sl.sum_rate(c, shipped.design(c)) > 0
    with pytest.raises(sl.InputError, match="models/no_such_model"):
        sl.beamformer("gnn=models/no_such_model", cfg)
