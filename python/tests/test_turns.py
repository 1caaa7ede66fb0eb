"""Sequential turns on the VecEnv (begin_turns / take_turn / step_turns): marl.sequential's protocol
and the collision shield for a learner written in Python."""
import numpy as np
import pytest

import skyloop as sl

# Six UAVs from a generated layout on the paper's 200 m square: crowded enough that uniformly random
# masked moves collide often.
CROWDED = {"env.oracle": "zf", "marl.encoder": "set", "marl.lookahead": True, "scenario.uavs": 6,
           "trajectory.layout": "generated"}


def pick(rng, mask):
    # Uniform over each row's allowed moves.
    return (rng.random(mask.shape) * mask).argmax(-1)


def moves_needed(env):
    p = env.positions()
    return np.rint(np.abs(p["uavs"][..., :2] - p["destinations"][..., :2]).sum(-1) / env.config["trajectory.d_fly_m"]).astype(int)


def test_turns_follow_the_shield_order_and_step_as_step_does():
    env, twin = sl.VecEnv(CROWDED, 4, 2), sl.VecEnv(CROWDED, 4, 2)
    o = env.reset()
    twin.reset()
    rng = np.random.default_rng(1)
    M, N = env.num_envs, env.num_agents
    later_rows_changed = 0
    for _ in range(40):
        need = moves_needed(env)
        home = need == 0
        turn = env.begin_turns()
        # Nothing is chosen yet: the first agent reads the slot's own observation.
        first = turn.agent >= 0
        assert np.array_equal(turn.obs[first], o.obs[first, turn.agent[first]])
        order = [[] for _ in range(M)]
        joint = np.full((M, N), env.spec["hover"], dtype=np.int64)
        while (turn.agent >= 0).any():
            a = pick(rng, turn.action_mask)
            for i in np.flatnonzero(turn.agent >= 0):
                n = turn.agent[i]
                # The shield only narrows the agent's masked moves, and always leaves one.
                assert turn.action_mask[i].sum() >= 1
                assert np.all(turn.action_mask[i] <= o.action_mask[i, n])
                if order[i]:
                    later_rows_changed += not np.array_equal(turn.obs[i], o.obs[i, n])
                order[i].append(n)
                joint[i, n] = a[i]
            turn = env.take_turn(a)
        for i in range(M):
            # Every UAV not yet home has one turn, least slack first (most moves still needed), ties by index.
            assert sorted(order[i]) == list(np.flatnonzero(~home[i]))
            keys = [(-need[i, n], n) for n in order[i]]
            assert keys == sorted(keys)
        r, ref = env.step_turns(), twin.step(joint)
        for x, y in zip(r[:7], ref[:7]):
            assert np.array_equal(x, y)
        assert np.array_equal(r.info["collisions"], ref.info["collisions"])
        o = r
    # With the earlier landings shown, the later agents' rows differ from the slot's plain ones.
    assert later_rows_changed > 0


def test_the_shield_in_turns_avoids_what_random_masked_moves_hit():
    def collisions(turns):
        env = sl.VecEnv(CROWDED, 4, 2)
        o = env.reset()
        rng = np.random.default_rng(1)
        total = 0
        for _ in range(40):
            if turns:
                t = env.begin_turns()
                while (t.agent >= 0).any():
                    t = env.take_turn(pick(rng, t.action_mask))
                o = env.step_turns()
            else:
                o = env.step(pick(rng, o.action_mask))
            total += int(o.info["collisions"].sum())
        return total
    plain, shielded = collisions(False), collisions(True)
    # Left are the meetings no move avoids (two UAVs with no slack left on one line).
    assert plain > 0 and shielded * 4 < plain, (plain, shielded)


def test_bad_turns_raise_and_corrupt_nothing():
    env, twin = sl.VecEnv(CROWDED, 2, 3), sl.VecEnv(CROWDED, 2, 3)
    env.reset(), twin.reset()
    with pytest.raises(sl.InputError, match="no turns begun"):
        env.take_turn(np.zeros(2, dtype=np.int64))
    with pytest.raises(sl.InputError, match="no turns begun"):
        env.step_turns()
    t, u = env.begin_turns(), twin.begin_turns()
    with pytest.raises(sl.InputError, match="has not chosen"):
        env.step_turns()
    for bad, message in [(np.zeros(3, dtype=np.int64), "shape [3]"), (np.zeros(2), "dtype float64"),
                         (np.full(2, 9, dtype=np.int64), "actions[0] = 9 is not allowed for agent"),
                         ("UP", "dtype")]:
        with pytest.raises(sl.InputError) as e:
            env.take_turn(bad)
        assert message in str(e.value)
    # Fly both in step until a turn refuses a move (the mask or the shield), then offer it in an
    # otherwise valid batch: refused, and nothing changes.
    rng = np.random.default_rng(4)
    refused = False
    for _ in range(40):
        while (t.agent >= 0).any():
            if not refused and (t.agent >= 0).all() and (t.action_mask[0] == 0).any():
                blocked = np.flatnonzero(t.action_mask[0] == 0)[0]
                with pytest.raises(sl.InputError, match=f"actions\\[0\\] = {blocked} is not allowed"):
                    env.take_turn(np.array([blocked, t.action_mask[1].argmax()]))
                refused = True
            a = pick(rng, t.action_mask)
            t, u = env.take_turn(a), twin.take_turn(a)
            assert np.array_equal(t.agent, u.agent) and np.array_equal(t.obs, u.obs)
        if refused:
            break
        r, q = env.step_turns(), twin.step_turns()
        assert np.array_equal(r.obs, q.obs)
        t, u = env.begin_turns(), twin.begin_turns()
    assert refused
    with pytest.raises(sl.InputError, match="every agent has chosen"):
        env.take_turn(np.zeros(2, dtype=np.int64))
    r, q = env.step_turns(), twin.step_turns()
    assert np.array_equal(r.obs, q.obs) and np.array_equal(r.reward, q.reward)
    # A step ends the turns.
    env.begin_turns()
    env.step(np.full((2, 6), env.spec["hover"], dtype=np.int64))
    with pytest.raises(sl.InputError, match="no turns begun"):
        env.step_turns()


def test_continuous_commands_have_no_turns():
    env = sl.VecEnv({"env.oracle": "zf", "trajectory.mobility": "continuous"}, 1, 0)
    env.reset()
    with pytest.raises(sl.InputError, match="continuous"):
        env.begin_turns()


def test_later_passes_show_the_intentions_and_fly_the_last():
    # marl.sequential_passes' protocol (src/planning/safety.cpp, take_turns): the order repeats, the
    # first agent of pass 2 sees the later agents at their moves of pass 1 and itself where it is,
    # and the last pass is flown.
    env, twin = sl.VecEnv(CROWDED, 4, 5), sl.VecEnv(CROWDED, 4, 5)
    env.reset(), twin.reset()
    hover = env.spec["hover"]
    rng = np.random.default_rng(2)
    unchanged = changed = 0
    for slot in range(30):
        moving = slot % 2 == 1  # in pass 1 the first agent leaves where it can; in odd slots the later ones as well
        turns = [[] for _ in range(env.num_envs)]  # (agent, obs, move, last) per environment
        turn = env.begin_turns(passes=2)
        while (turn.agent >= 0).any():
            a = pick(rng, turn.action_mask)
            for i in np.flatnonzero(turn.agent >= 0):
                m = turn.action_mask[i]
                if not turn.last[i]:
                    away = np.flatnonzero((m == 1) & (np.arange(len(m)) != hover))
                    a[i] = rng.choice(away) if len(away) and (not turns[i] or moving) else (hover if m[hover] else m.argmax())
                turns[i].append((turn.agent[i], turn.obs[i].copy(), a[i], turn.last[i]))
            turn = env.take_turn(a)
        assert not turn.last.any()
        joint = np.full((env.num_envs, env.num_agents), hover, dtype=np.int64)
        for i in range(env.num_envs):
            p1 = [r for r in turns[i] if not r[3]]
            p2 = [r for r in turns[i] if r[3]]
            assert [r[0] for r in p1] == [r[0] for r in p2]  # the same order twice, pass 1 first
            assert all(not r[3] for r in turns[i][:len(p1)])
            for n, _, move, _ in p2:
                joint[i, n] = move
            if len(p1) < 2:
                continue
            later_moved = any(r[2] != hover for r in p1[1:])
            same = np.array_equal(p1[0][1], p2[0][1])
            if not later_moved:  # its own move of pass 1 is no intention: its row is the one of pass 1
                assert same, (slot, i)
                unchanged += 1
            else:
                changed += not same
        r, ref = env.step_turns(), twin.step(joint)  # the moves of the last pass are flown
        for x, y in zip(r[:7], ref[:7]):
            assert np.array_equal(x, y)
    assert unchanged > 10 and changed > 10, (unchanged, changed)


def test_passes_default_to_the_configuration_and_are_checked():
    env = sl.VecEnv({**CROWDED, "marl.sequential": True, "marl.sequential_passes": 3}, 1, 1)
    env.reset()
    turn, agents = env.begin_turns(), []
    while (turn.agent >= 0).any():
        agents.append((int(turn.agent[0]), bool(turn.last[0])))
        turn = env.take_turn(turn.action_mask.argmax(-1))
    flying = len(agents) // 3
    assert flying > 0 and len(agents) == 3 * flying
    assert agents[:flying] == agents[flying:2 * flying] and [a for a, _ in agents[:flying]] == [a for a, _ in agents[2 * flying:]]
    assert [last for _, last in agents] == [False] * 2 * flying + [True] * flying
    one = env.begin_turns(passes=1)
    assert one.last[0]
    for bad, message in [(0, "passes = 0 is out of range: allowed an integer in [1, 4]"),
                         (sl.MAX_SEQUENTIAL_PASSES + 1, "passes = 5 is out of range"),
                         (1.5, "passes = 1.5 has the wrong type"), ("2", "passes = '2' has the wrong type")]:
        with pytest.raises(sl.InputError) as e:
            env.begin_turns(passes=bad)
        assert message in str(e.value)
