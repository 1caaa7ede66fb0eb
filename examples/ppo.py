#!/usr/bin/env python3
"""Multi-agent PPO on skyloop's VecEnv, in one file (CleanRL style): a parameter-shared,
action-masked actor on each UAV's observation and one-hot id, a centralised critic on the
agent-specific global state (MAPPO), GAE, the clipped surrogate and value losses.

    /usr/bin/python3 examples/ppo.py --steps 200000 --seed 1
    (PYTHONPATH=build/python from a build tree, or after scripts/install-python)

Default scenario: the small one of the C++ MAPPO test (2 UAVs on a 120 m square, 7 x 7 grid,
T_max = 12, ZF as the rate oracle); --paper for the paper's scenario (GNN oracle). Prints
charts/episode_reward, charts/objective and charts/success as it trains, then evaluates the greedy
policy on users it never saw and the exact optimum on the same users.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch
import torch.nn as nn

import skyloop as sl

SMALL = {
    "scenario": {"area_x_m": 120.0, "area_y_m": 120.0, "users": 6},
    "trajectory": {"starts": [[0.0, 0.0], [120.0, 120.0]], "destinations": [[120.0, 40.0], [0.0, 80.0]], "t_max": 12},
    "env": {"oracle": "zf"},
    # The environment's action mask is then arrival-only, so the agent must learn to come home;
    # with the default reachability mask every episode comes home by construction (docs/concepts/generalisation.md,
    # "Generalisation").
    "marl": {"action_mask": False},
}


def layer(i, o, std=np.sqrt(2)):
    m = nn.Linear(i, o)
    nn.init.orthogonal_(m.weight, std)
    nn.init.zeros_(m.bias)
    return m


class Agent(nn.Module):
    def __init__(self, obs_dim, state_dim, actions=len(sl.ACTIONS), hidden=64):
        super().__init__()
        self.actor = nn.Sequential(layer(obs_dim, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh(),
                                   layer(hidden, actions, 0.01))
        self.critic = nn.Sequential(layer(state_dim, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh(),
                                    layer(hidden, 1, 1.0))

    def dist(self, obs, mask):
        logits = self.actor(obs).masked_fill(mask == 0, -1e8)
        return torch.distributions.Categorical(logits=logits)

    def value(self, state):
        return self.critic(state).squeeze(-1)


def with_id(obs):
    """[M, N, obs] -> [M, N, obs + N]: each agent's observation and its one-hot id (parameter sharing)."""
    M, N, _ = obs.shape
    return np.concatenate([obs, np.broadcast_to(np.eye(N, dtype=np.float32), (M, N, N))], axis=-1)


def evaluate(agent, cfg, seed, episodes=1):
    """The greedy (argmax, masked) policy on fresh users; returns episode records."""
    env = sl.VecEnv(cfg, 1, seed)
    out = []
    for e in range(episodes):
        o = env.reset(seed + e if e else None)
        users = env.users(0)
        collisions = boundary = 0
        while True:
            with torch.no_grad():
                logits = agent.actor(torch.as_tensor(with_id(o.obs)))
                logits = logits.masked_fill(torch.as_tensor(o.action_mask) == 0, -1e8)
            r = env.step(logits.argmax(-1).numpy())
            if r.terminated[0] or r.truncated[0]:
                out.append({"objective": float(r.info["objective"][0]), "success": bool(r.info["success"][0]),
                            "home": int(r.info["home"][0]), "T": int(r.info["T"][0]), "users": users,
                            "collisions": collisions + int(r.info["collisions"][0]),
                            "boundary": boundary + int(r.info["boundary"][0])})
                break
            collisions += int(r.info["collisions"][0])
            boundary += int(r.info["boundary"][0])
            o = r
    return out


def train(config=None, steps=200_000, num_envs=16, num_steps=32, seed=1, lr=3e-4, gamma=0.99, lam=0.95, clip=0.2,
          epochs=4, minibatches=4, ent_coef=0.03, vf_coef=0.5, max_grad=10.0, log_every=0, threads=1):
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    cfg = sl.config(overrides=config if config is not None else SMALL)
    env = sl.VecEnv(cfg, num_envs, seed)
    M, N = env.num_envs, env.num_agents
    obs_dim, state_dim = env.obs_size + N, env.agent_state_size
    agent = Agent(obs_dim, state_dim, env.num_actions)
    opt = torch.optim.Adam(agent.parameters(), lr=lr, eps=1e-5)

    # Rollout storage [T, M, N, ...].
    b_obs = torch.zeros(num_steps, M, N, obs_dim)
    b_state = torch.zeros(num_steps, M, N, state_dim)
    b_mask = torch.zeros(num_steps, M, N, env.num_actions, dtype=torch.int8)
    stay = sl.ACTIONS.index("STAY")
    b_act = torch.zeros(num_steps, M, N, dtype=torch.long)
    b_logp = torch.zeros(num_steps, M, N)
    b_val = torch.zeros(num_steps, M, N)
    b_rew = torch.zeros(num_steps, M)
    b_done = torch.zeros(num_steps, M)
    b_active = torch.zeros(num_steps, M, N)  # 0 for arrived agents: out of the actor loss

    o = env.reset()
    obs, state, mask = torch.as_tensor(with_id(o.obs)), torch.as_tensor(o.agent_state), torch.as_tensor(o.action_mask)
    iterations = max(1, steps // (num_steps * M))
    history = []
    t0 = time.time()
    for it in range(iterations):
        for t in range(num_steps):
            b_obs[t], b_state[t], b_mask[t] = obs, state, mask
            b_active[t] = ((mask.sum(-1) - mask[..., stay]) > 0).float()  # a move other than STAY allowed
            with torch.no_grad():
                d = agent.dist(obs, mask)
                a = d.sample()
                b_act[t], b_logp[t], b_val[t] = a, d.log_prob(a), agent.value(state)
            r = env.step(a.numpy())
            done = r.terminated | r.truncated
            b_rew[t], b_done[t] = torch.as_tensor(r.reward), torch.as_tensor(done.astype(np.float32))
            for i in np.flatnonzero(done):
                history.append((float(r.info["episode_reward"][i]), float(r.info["objective"][i]), bool(r.info["success"][i])))
            obs, state, mask = torch.as_tensor(with_id(r.obs)), torch.as_tensor(r.agent_state), torch.as_tensor(r.action_mask)

        # GAE per (environment, agent) on the team reward.
        with torch.no_grad():
            next_v = agent.value(state)
            adv = torch.zeros(num_steps, M, N)
            last = torch.zeros(M, N)
            for t in reversed(range(num_steps)):
                nv = next_v if t == num_steps - 1 else b_val[t + 1]
                keep = (1.0 - b_done[t]).unsqueeze(-1)
                delta = b_rew[t].unsqueeze(-1) + gamma * nv * keep - b_val[t]
                last = delta + gamma * lam * keep * last
                adv[t] = last
            ret = adv + b_val

        flat = lambda x: x.reshape(num_steps * M * N, *x.shape[3:])  # noqa: E731
        f_obs, f_state, f_mask, f_act = flat(b_obs), flat(b_state), flat(b_mask), flat(b_act)
        f_logp, f_val, f_adv, f_ret, f_active = flat(b_logp), flat(b_val), flat(adv), flat(ret), flat(b_active)
        size = f_obs.shape[0]
        mb = size // minibatches
        for _ in range(epochs):
            perm = torch.randperm(size)
            for s in range(0, size, mb):
                idx = perm[s:s + mb]
                d = agent.dist(f_obs[idx], f_mask[idx])
                logp = d.log_prob(f_act[idx])
                ratio = (logp - f_logp[idx]).exp()
                act = f_active[idx]
                a_n = f_adv[idx]
                a_n = (a_n - a_n[act > 0].mean()) / (a_n[act > 0].std() + 1e-8) if act.sum() > 1 else a_n
                surrogate = torch.min(ratio * a_n, ratio.clamp(1 - clip, 1 + clip) * a_n)
                denom = act.sum().clamp(min=1.0)
                policy_loss = -(surrogate * act).sum() / denom
                entropy = (d.entropy() * act).sum() / denom
                v = agent.value(f_state[idx])
                v_clip = f_val[idx] + (v - f_val[idx]).clamp(-clip, clip)
                value_loss = 0.5 * torch.max((v - f_ret[idx]) ** 2, (v_clip - f_ret[idx]) ** 2).mean()
                loss = policy_loss - ent_coef * entropy + vf_coef * value_loss
                opt.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), max_grad)
                opt.step()
        if log_every and (it + 1) % log_every == 0 and history:
            recent = history[-50:]
            print(f"steps {(it + 1) * num_steps * M:>8}  charts/episode_reward {np.mean([h[0] for h in recent]):8.2f}  "
                  f"charts/objective {np.mean([h[1] for h in recent]):7.3f}  charts/success {np.mean([h[2] for h in recent]):.2f}  "
                  f"losses/policy {policy_loss.item():+.4f}  losses/value {value_loss.item():.3f}  "
                  f"charts/steps_per_s {(it + 1) * num_steps * M / (time.time() - t0):.0f}", flush=True)
    return agent, cfg, history


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=200_000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--paper", action="store_true", help="the paper's scenario (3 UAVs, 200 m, GNN oracle)")
    a = p.parse_args()
    agent, cfg, _ = train({} if a.paper else SMALL, steps=a.steps, num_envs=a.envs, seed=a.seed, log_every=20)
    for rec in evaluate(agent, cfg, seed=1000 + a.seed, episodes=3):
        opt = sl.plan(cfg, "optimal", users=rec["users"])
        print(f"held-out users: objective {rec['objective']:.3f} (optimum {opt['objective']:.3f}, "
              f"{100 * rec['objective'] / opt['objective']:.1f}%), UAVs home {rec['home']}, T = {rec['T']}, "
              f"collisions {rec['collisions']}, boundary events {rec['boundary']}")


if __name__ == "__main__":
    main()
