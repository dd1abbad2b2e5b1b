"""
Why do shared centralized critics get worse at N = 6 on simple_spread? Trains MADDPG (64-64, batch 256, Gaussian
noise 0.1, as ``sharing_spread.py``) with several sharing settings and prints, every ``--every`` steps:

- ``return``: the deterministic evaluation return (``--eval-episodes`` episodes on a fresh env);
- ``Q``: the critics' mean value of the current policy, Q_i(s, pi(s)), over 2,000 states from the replay buffer
  (mean over agents), next to ``r/(1-g)``, the buffer's mean reward per agent and step divided by 1 - gamma: the
  value of the buffer's average behaviour continued for ever. Every reward of simple_spread is at most 0, so a
  positive Q is overestimation beyond doubt;
- ``sat``: the share of the actors' action components within 0.01 of the bounds on those states (1.0: every action
  saturated, i.e. agents always pushing at full force).

    python benchmarks/sharing_diagnostics.py                                  # N=6, 20,000 steps, seed 0
    python benchmarks/sharing_diagnostics.py --configs both both_td3 --seeds 0 1 --steps 30000

Configurations: ``none`` (one actor and critic per agent), ``actors`` (shared actors), ``both`` (shared actors and
critics); a ``_td3`` suffix adds TD3's clipped double Q, delayed actor and target smoothing (``both_td3``), an ``_lr``
suffix divides the learning rate by N (``both_lr``).
"""

import argparse
import time

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise

from benchmarks_common import spread
from sb3_macb import MADDPG

TD3 = dict(policy_delay=2, target_policy_noise=0.2)


def config_kwargs(name: str, n: int) -> tuple[dict, dict]:
    """(MADDPG kwargs, policy_kwargs) of a configuration."""
    base, _, suffix = name.partition("_")
    shares = {"none": {}, "actors": dict(share_parameters="all"), "both": dict(share_parameters="all", share_critics=True)}
    if base not in shares or suffix not in ("", "td3", "lr"):
        raise SystemExit(f"Unknown configuration {name!r}: none, actors or both, optionally with _td3 or _lr")
    if suffix == "td3":
        return {**shares[base], **TD3}, {"n_critics": 2}
    if suffix == "lr":
        return {**shares[base], "learning_rate": 1e-3 / n}, {}
    return shares[base], {}


class Probe(BaseCallback):
    """Every ``every`` steps: evaluation return, mean Q of the policy, reward scale and action saturation."""

    def __init__(self, n: int, every: int, eval_episodes: int, seed: int) -> None:
        super().__init__()
        self.n, self.every, self.eval_episodes, self.seed = n, every, eval_episodes, seed

    def _on_step(self) -> bool:
        if self.num_timesteps % self.every:
            return True
        model: MADDPG = self.model  # type: ignore[assignment]
        buffer = model.replay_buffer
        size = buffer.buffer_size if buffer.full else buffer.pos
        rng = np.random.default_rng(0)
        idx = rng.integers(0, size, 2000)
        obs = th.as_tensor(buffer.observations[idx, 0], dtype=th.float32).unsqueeze(0)  # (1 run, batch, obs)
        with th.no_grad():
            actions = model.actor(obs)
            q = model.critic(obs, actions)[0]  # (n_runs, n_agents, batch) of the first critic
        saturated = float((actions.abs() > 0.99).float().mean())
        reward = float(np.mean(buffer.rewards[:size]))
        env = Monitor(spread(self.n))
        env.reset(seed=1000 + self.seed)
        result = evaluate_policy(model, env, n_eval_episodes=self.eval_episodes)[0]
        row = (self.num_timesteps, result, float(q.mean()), reward / (1 - model.gamma), saturated)
        print(f"  step {row[0]:>6}: return {row[1]:8.1f}   Q {row[2]:8.2f}   r/(1-g) {row[3]:8.2f}   sat {row[4]:.2f}",
              flush=True)  # fmt: skip
        return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agents", type=int, default=6)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--every", type=int, default=5_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--configs", nargs="+", default=["none", "actors", "both", "both_td3"])
    parser.add_argument("--eval-episodes", type=int, default=20)
    args = parser.parse_args()
    for name in args.configs:  # unknown names fail before anything is trained
        config_kwargs(name, args.agents)
    th.set_num_threads(1)
    print(f"simple_spread N={args.agents}, {args.steps} steps, 64-64, batch 256, noise 0.1, torch {th.__version__}, 1 thread")
    for name in args.configs:
        for seed in args.seeds:
            print(f"{name}, seed {seed}:", flush=True)
            kwargs, policy_kwargs = config_kwargs(name, args.agents)
            env = spread(args.agents)
            dim = env.action_space.shape[0]
            model = MADDPG("MlpPolicy", env, action_noise=NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)),
                           learning_starts=1000, batch_size=256, seed=seed,
                           policy_kwargs={"net_arch": [64, 64], **policy_kwargs}, **kwargs)  # fmt: skip
            start = time.perf_counter()
            model.learn(args.steps, callback=Probe(args.agents, args.every, args.eval_episodes, seed))
            print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
