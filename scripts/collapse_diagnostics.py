"""
What a collapsed Communicative Navigation run looks like inside: loads saved packs (a checkpoint's or a finished
run's ``model.zip``), plays ``--episodes`` noise-free episodes with each run's policy and prints per run:

- ``any`` / ``final``: any-step and final-step success of those episodes (as the evaluations);
- ``sat spk`` / ``sat lis``: the share of the speaker's and the listener's action components within 0.01 of a bound
  (``|a| > 0.99`` in the actors' [-1, 1] units);
- ``pre lis``: the listener's mean pre-tanh output size (above ~3 the tanh is flat: the actor's gradient through it
  is below 1% of its unsaturated size, so a saturated actor hardly moves back);
- ``Q spk`` / ``Q lis``: each agent's critic's mean Q(s, pi(s)) on the visited states, beside the range any true
  value can take (``Q range``): with the sparse reward in {-1, 0} plus a bonus in [0, beta] on every transition, the
  discounted value lies in [-1/(1-gamma), beta/(1-gamma)], and with the constant bonus (exactly beta) in
  [(beta-1)/(1-gamma), beta/(1-gamma)]; ``Q out``: the share of Q values more than 1 (one step's worst reward)
  outside that range (overestimation or underestimation beyond doubt, not a fitting error at a bound).

    python scripts/collapse_diagnostics.py logs/archive/seed_1/step_*.zip \\
        --experiment logs/reproduce/CommunicativeNavigation-sparse-paper/seed_1/experiment.json

``--experiment`` names the pack's runs by their variants (default: run 0, run 1, ...). Runs started with
``--keep-models`` (``scripts/reproduce.py``, ``sb3-macb train``) keep every checkpoint's model in ``<work>/models/``.

**Interventions.** Given a checkpoint folder (``model.zip``, ``buffer.npz``, ``state.pkl``, as
``scripts/reproduce.py --checkpoint-freq`` writes them) and ``--continue-steps N``, the pack is also trained on from
the checkpoint's exact state (networks, optimizers, replay buffer, count tables, envs, random streams) for N more
steps per run, once for every ``--preactivation-reg`` value (``MADDPG(preactivation_reg=...)``), and measured again.
Nothing is written: the checkpoint and the runs' files stay as they are.

    python scripts/collapse_diagnostics.py logs/reproduce/CommunicativeNavigation-sparse-paper/seed_1/checkpoint/step_140000 \\
        --experiment logs/reproduce/CommunicativeNavigation-sparse-paper/seed_1/experiment.json \\
        --continue-steps 5000 --preactivation-reg 0 1e-3

A post-hoc diagnosis: it decides nothing registered.
"""

import argparse
import json
import os
import re

import numpy as np
import torch as th

import sb3_macb
from sb3_macb import MADDPG
from sb3_macb.envs.vec_tasks import make_task_vec_env
from sb3_macb.zoo.experiment import load_checkpoint, restore_global_rngs

ENV_ID = "sb3_macb/CommunicativeNavigation-v0"


def run_labels(experiment: str | None, n_runs: int) -> list[tuple[str, float, bool]]:
    """(variant, beta, constant bonus?) of each run of the pack, from ``experiment.json`` (beta 0 without a bonus)."""
    if experiment is None:
        return [(f"run {k}", 0.0, False) for k in range(n_runs)]
    with open(experiment) as file:
        runs = json.load(file)["config"]["runs"]
    if len(runs) != n_runs:
        raise SystemExit(f"{experiment} has {len(runs)} runs, the model {n_runs}: not this pack's experiment")
    labels = []
    for run in runs:
        bonus = run["hyperparams"].get("exploration") or {}
        constant = bool(bonus) and bonus.get("counts", True) is False
        labels.append(("+".join(run["variants"]) or "run", float(bonus.get("beta", 0.0)), constant))
    return labels


def diagnose(model: MADDPG, k: int, beta: float, constant: bool, episodes: int, seed: int) -> dict[str, float]:
    """Play ``episodes`` noise-free episodes with run ``k`` of ``model`` and measure it (see the module docstring)."""
    solo = model.get_run(k)
    layout = solo.agent_layout
    env = make_task_vec_env(ENV_ID, episodes, {"reward": "sparse"})
    env.seed(seed)
    obs = env.reset()
    observations, actions, raws = [], [], []
    reached = np.zeros(episodes, dtype=bool)
    final = np.zeros(episodes, dtype=bool)
    for _ in range(10_000):
        with th.no_grad():
            obs_t = th.as_tensor(obs, dtype=th.float32)
            raw = solo.actor.raw(obs_t)  # one pass: the squashed action and the env's action follow from it
            action = solo.actor.squash(raw)
        observations.append(obs_t)
        actions.append(action)
        raws.append(raw)
        obs, _, dones, infos = env.step(solo.policy.unscale_action(action.numpy()))  # as predict(deterministic=True)
        success = np.array([info["agent_infos"]["listener_0"]["success"] for info in infos])
        reached |= success
        if dones.all():
            final = success
            break
    else:
        raise RuntimeError("the episodes did not end")
    obs_all, act_all, raw_all = th.cat(observations), th.cat(actions), th.cat(raws)
    with th.no_grad():
        q = solo.critic(obs_all, act_all)[0, 0]  # (n_agents, steps * episodes) of the first critic
    bounds = ((beta - 1.0 if constant else -1.0) / (1.0 - solo.gamma), beta / (1.0 - solo.gamma))
    out: dict[str, float] = {"any": float(reached.mean()), "final": float(final.mean())}
    start = 0
    for i, name in enumerate(layout.agents):
        width = layout.action_dims[i]
        part = act_all[:, start : start + width]
        short = "spk" if name.startswith("speaker") else "lis" if name.startswith("listener") else name
        out[f"sat {short}"] = float((part.abs() > 0.99).float().mean())
        if short == "lis":
            out["pre lis"] = float(raw_all[:, start : start + width].abs().mean())
        out[f"Q {short}"] = float(q[i].mean())
        start += width
    out["Q out"] = float(((q < bounds[0] - 1.0) | (q > bounds[1] + 1.0)).float().mean())
    out["Q range"] = bounds  # type: ignore[assignment]
    return out


def continue_from_checkpoint(folder: str, steps: int, preactivation_reg: float) -> MADDPG:
    """
    The pack of checkpoint ``folder`` trained ``steps`` more steps per run with ``preactivation_reg``, from the
    checkpoint's exact state (as ``Experiment`` resumes it, without its evaluation callback: nothing is written).
    """
    model, state = load_checkpoint(folder, allow_other_version=True)  # (a checkpoint this machine's runs wrote)
    if state.get("sb3_macb") != sb3_macb.__version__:
        print(f"note: {folder} was written by sb3_macb {state.get('sb3_macb')}, continued with {sb3_macb.__version__}")
    restore_global_rngs(state)
    model.preactivation_reg = float(preactivation_reg)
    model.learn(steps * model.n_runs, reset_num_timesteps=False)
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="+", help="model.zip files of packs (e.g. archived checkpoints)")
    parser.add_argument("--experiment", default=None, help="the pack's experiment.json (names the runs)")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=12345)
    parser.add_argument("--continue-steps", type=int, default=0,
                        help="train checkpoint folders on for this many steps per run, then measure again")
    parser.add_argument("--preactivation-reg", type=float, nargs="+", default=[0.0],
                        help="preactivation_reg values for --continue-steps (one continuation each)")  # fmt: skip
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    if args.continue_steps < 0:
        parser.error(f"--continue-steps must be at least 0, got {args.continue_steps}")
    for path in args.models:
        if not os.path.exists(path):
            parser.error(f"{path} does not exist")
        if args.continue_steps and not os.path.isfile(os.path.join(path, "state.pkl")):
            parser.error(f"--continue-steps needs checkpoint folders (model.zip, buffer.npz, state.pkl): {path} is not one")
    th.set_num_threads(1)

    def step_of(path: str) -> int:
        found = re.findall(r"\d+", os.path.basename(path))
        return int(found[-1]) if found else 0

    def rows(name: str, model: MADDPG) -> None:
        for k, (label, beta, constant) in enumerate(run_labels(args.experiment, model.n_runs)):
            d = diagnose(model, k, beta, constant, args.episodes, args.seed)
            low, high = d["Q range"]  # type: ignore[misc]
            print(f"| {name} | {label} | {d['any']:.2f} | {d['final']:.2f} | {d['sat spk']:.2f} | "
                  f"{d['sat lis']:.2f} | {d['pre lis']:.2f} | {d['Q spk']:.1f} | {d['Q lis']:.1f} | "
                  f"[{low:.0f}, {high:.0f}] | {d['Q out']:.2f} |", flush=True)  # fmt: skip

    print("| model | run | any | final | sat spk | sat lis | pre lis | Q spk | Q lis | Q range | Q out |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(args.models, key=step_of):
        name = os.path.basename(os.path.normpath(path))
        rows(name, MADDPG.load(os.path.join(path, "model.zip") if os.path.isdir(path) else path, device="cpu"))
        for reg in args.preactivation_reg if args.continue_steps else []:
            rows(f"{name} +{args.continue_steps} (reg {reg:g})", continue_from_checkpoint(path, args.continue_steps, reg))


if __name__ == "__main__":
    main()
