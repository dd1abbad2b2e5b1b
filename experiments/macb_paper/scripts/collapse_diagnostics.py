"""
What a collapsed Communicative Navigation run looks like inside: loads saved packs (a checkpoint's or a finished
run's ``model.zip``), plays ``--episodes`` noise-free episodes with each run's policy and prints per run:

- ``any`` / ``final``: any-step and final-step success of those episodes (as the evaluations);
- ``sat spk`` / ``sat lis``: the share of the speaker's and the listener's action components within 0.01 of a bound
  (``|a| > 0.99`` in the actors' [-1, 1] units);
- ``pre spk`` / ``pre lis``: each agent's mean pre-tanh output size (above ~3 the tanh is flat: the actor's gradient
  through it is below 1% of its unsaturated size, so a saturated actor hardly moves back);
- ``Q spk`` / ``Q lis``: each agent's critic's mean Q(s, pi(s)) on the visited states, beside the range any true
  value can take (``Q range``): with the sparse reward in {-1, 0} plus a bonus in [0, beta] on every transition, the
  discounted value lies in [-1/(1-gamma), beta/(1-gamma)], and with the constant bonus (exactly beta) in
  [(beta-1)/(1-gamma), beta/(1-gamma)]; ``Q out``: the share of Q values more than 1 (one step's worst reward)
  outside that range (overestimation or underestimation beyond doubt, not a fitting error at a bound).

``--task nav`` measures 2-Agent Navigation runs the same way, with a column per agent (``agent_0``, ``agent_1``), the
task's shared success, and its sparse reward's range [-1.5, 0] in place of {-1, 0}; the other tables (``--per-goal``,
``--on-buffer``) are Communicative Navigation's only.

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

**Who says what.** With ``--per-goal``, a third table splits the same noise-free episodes by goal landmark: the
speaker's message at the first step (its mean, and its largest spread within the goal: the speaker sees only the
goal's colour, so a deterministic speaker sends one message per goal), the any-step and final-step success for that
goal, and where the listener is at the episode's last step: within 0.15 of landmark 0, 1 or 2, or of none. A
speaker that sends one message for two goals, or a listener that goes to one landmark whatever it hears, shows here.

**The critics on their own data.** With ``--on-buffer``, each checkpoint folder's replay buffer is read too, and for
each run, over the whole buffer (``all``) and over its newest ``--recent`` transitions (``newest``), a second table
gives, on ``--samples`` transitions drawn from the run's own column (seed ``--seed``):

- ``Q spk (s,a)`` / ``Q lis (s,a)``: each critic on the stored state and joint action;
- ``TD spk`` / ``TD lis``: its mean error against its own target, r + bonus + gamma * Q'(s', pi'(s')) (target
  networks; time limits bootstrapped, as in training; the bonus from the run's own counts, as a sampled minibatch
  gets it), and ``|TD|`` its mean size. A critic that fits its data has |TD| well below 1; a mean TD that is large
  and of one sign is a critic running away from its own target;
- ``gap spk`` / ``gap lis``: at s', the critic's (target network's) value of the target policy's joint action minus
  its value of the joint action the run actually took next (the following row of the same episode; transitions
  that end an episode are left out), and ``gap(lis)`` the same with only the listener's action replaced. The target
  bootstraps from the policy's action, so a critic that holds a steady gap G fits a level about (r + gamma G) /
  (1 - gamma), i.e. 100 G at gamma 0.99 away from where the data's own actions would put it: a small error in how
  a critic ranks the policy's action against the taken one becomes a large error in its values. With the true Q,
  G is bounded by the range of values; ``r`` is the mean reward with bonus;
- ``end spk`` / ``end lis``: the critic's target value Q'(s', pi'(s')) at the transitions that end an episode (time
  limits, bootstrapped): the states the target takes its values from last, beside ``lis dist end``, the listener's
  distance to the nearest landmark there;
- ``lis dist`` / ``lis speed``: the listener's mean distance to the nearest landmark and its mean speed in those
  transitions (where its behaviour took it).

    python scripts/collapse_diagnostics.py logs/reproduce/CommunicativeNavigation-sparse-paper/seed_1/checkpoint/step_300000 \\
        --experiment logs/reproduce/CommunicativeNavigation-sparse-paper/seed_1/experiment.json --on-buffer

With ``--buffer-of <checkpoint folder>``, earlier models of the same pack (archived ``model.zip`` files) are measured
on that checkpoint's buffer, each on the rows it had collected by its own step (the buffer only grows until it is
full, so those rows are exactly the model's own data). The bonus then comes from the checkpoint's counts, not the
model's: exact for the constant bonus, and for MACB at k = 512 a difference on a few transitions.

A post-hoc diagnosis: it decides nothing registered.
"""

import argparse
import inspect
import json
import os
import re
from typing import Any

import numpy as np
import torch as th

import sb3_macb
from sb3_macb import MADDPG
from sb3_macb.envs import communicative_navigation_v0
from sb3_macb.envs.vec_tasks import make_task_vec_env
from sb3_macb.zoo.experiment import load_checkpoint, restore_global_rngs

ENV_ID = "sb3_macb/CommunicativeNavigation-v0"
# per task (``--task``): its env id and the lowest sparse reward of one step, which bounds the values from below
TASKS = {"comm-sparse": (ENV_ID, -1.0), "nav": ("sb3_macb/TwoAgentNavigation-v0", -1.5)}
# the task's default success radius (the runs diagnosed here use the default), read from the task's signature
SUCCESS_RADIUS = inspect.signature(communicative_navigation_v0.parallel_env).parameters["success_radius"].default


def run_labels(experiment: str | None, model: MADDPG) -> list[tuple[str, float, bool]]:
    """
    (name, beta, constant bonus?) of each run of the pack: the bonus from the model itself (beta 0 without one), the
    name from ``experiment.json`` if given (its variants), else ``run k``.
    """
    bonuses = [(0.0, False) if e is None else (float(e.beta), not e.counts) for e in model.explorations]
    if experiment is None:
        return [(f"run {k}", beta, constant) for k, (beta, constant) in enumerate(bonuses)]
    with open(experiment) as file:
        runs = json.load(file)["config"]["runs"]
    if len(runs) != model.n_runs:
        raise SystemExit(f"{experiment} has {len(runs)} runs, the model {model.n_runs}: not this pack's experiment")
    return [("+".join(run["variants"]) or "run", beta, constant) for run, (beta, constant) in zip(runs, bonuses)]


def diagnose(
    model: MADDPG, k: int, beta: float, constant: bool, episodes: int, seed: int, task: str = "comm-sparse"
) -> dict[str, float]:
    """
    Play ``episodes`` noise-free episodes with run ``k`` of ``model`` and measure it (see the module docstring).

    :param task: a key of ``TASKS``: the task the model was trained on (its sparse reward).
    """
    solo = model.get_run(k)
    layout = solo.agent_layout
    env_id, lowest_reward = TASKS[task]
    # whose info carries the task's success: Communicative Navigation's listener; 2-Agent Navigation's is shared
    reporter = layout.agents[agent_index(layout, "listener")] if task == "comm-sparse" else layout.agents[0]
    env = make_task_vec_env(env_id, episodes, {"reward": "sparse"})
    env.seed(seed)
    obs = env.reset()
    observations, actions, raws = [], [], []
    reached = np.zeros(episodes, dtype=bool)
    final = np.zeros(episodes, dtype=bool)
    for _ in range(10_000):
        with th.no_grad():
            obs_t = th.as_tensor(obs, dtype=th.float32, device=solo.device)
            raw = solo.actor.raw(obs_t)  # one pass: the squashed action and the env's action follow from it
            action = solo.actor.squash(raw)
        observations.append(obs_t)
        actions.append(action)
        raws.append(raw)
        obs, _, dones, infos = env.step(solo.policy.unscale_action(action.cpu().numpy()))  # as predict(deterministic=True)
        success = np.array([info["agent_infos"][reporter]["success"] for info in infos])
        reached |= success
        if dones.all():
            final = success
            break
    else:
        raise RuntimeError("the episodes did not end")
    obs_all, act_all, raw_all = th.cat(observations), th.cat(actions), th.cat(raws)
    with th.no_grad():
        q = solo.critic(obs_all, act_all)[0, 0]  # (n_agents, steps * episodes) of the first critic
    low = lowest_reward + beta if constant else lowest_reward
    bounds = (low / (1.0 - solo.gamma), beta / (1.0 - solo.gamma))
    out: dict[str, float] = {"any": float(reached.mean()), "final": float(final.mean())}
    start = 0
    for i, name in enumerate(layout.agents):
        width = layout.action_dims[i]
        part = act_all[:, start : start + width]
        short = short_name(name)
        out[f"sat {short}"] = float((part.abs() > 0.99).float().mean())
        out[f"pre {short}"] = float(raw_all[:, start : start + width].abs().mean())
        out[f"Q {short}"] = float(q[i].mean())
        start += width
    out["Q out"] = float(((q < bounds[0] - 1.0) | (q > bounds[1] + 1.0)).float().mean())
    out["Q range"] = bounds  # type: ignore[assignment]
    return out


def short_name(agent: str) -> str:
    """``spk`` / ``lis`` for the speaker and the listener (the tables' column names), other agents by name."""
    return "spk" if agent.startswith("speaker") else "lis" if agent.startswith("listener") else agent


def agent_index(layout: Any, prefix: str) -> int:
    """The index of the first agent whose name starts with ``prefix``."""
    return next(i for i, name in enumerate(layout.agents) if name.startswith(prefix))


def landmark_distances(listener_obs: np.ndarray) -> np.ndarray:
    """(n, 3) distances to the three landmarks from listener observations (velocity, then the landmarks relative)."""
    return np.linalg.norm(listener_obs[:, 2:8].reshape(-1, 3, 2), axis=-1)


def per_goal(model: MADDPG, k: int, episodes: int, seed: int) -> list[dict[str, Any]]:
    """
    What run ``k``'s speaker says for each goal and where its listener goes: ``episodes`` noise-free episodes, grouped
    by goal landmark (see the module docstring).
    """
    solo = model.get_run(k)
    layout = solo.agent_layout
    speaker, listener = agent_index(layout, "speaker"), agent_index(layout, "listener")
    env = make_task_vec_env(ENV_ID, episodes, {"reward": "sparse"})
    env.seed(seed)
    obs = env.reset()
    goals = obs[:, layout.obs_slices[speaker]].argmax(axis=1)  # the goal's colour: its largest component is its index
    reached = np.zeros(episodes, dtype=bool)
    messages = None
    for _ in range(10_000):
        with th.no_grad():
            obs_t = th.as_tensor(obs, dtype=th.float32, device=solo.device)
            action = solo.policy.unscale_action(solo.actor(obs_t).cpu().numpy())
        if messages is None:
            messages = action[:, layout.action_slices[speaker]]  # the message of the first step
        obs, _, dones, infos = env.step(action)
        success = np.array([info["agent_infos"][layout.agents[listener]]["success"] for info in infos])
        reached |= success
        if dones.all():
            break
    else:
        raise RuntimeError("the episodes did not end")
    final_obs = np.stack([info["terminal_observation"] for info in infos])[:, layout.obs_slices[listener]]
    distances = landmark_distances(final_obs)
    ends = np.where(distances.min(axis=1) <= SUCCESS_RADIUS, distances.argmin(axis=1), 3)  # 3: at none
    rows = []
    for goal in range(3):
        chosen = goals == goal
        rows.append({
            "goal": goal, "episodes": int(chosen.sum()),
            "any": float(reached[chosen].mean()) if chosen.any() else float("nan"),
            "final": float((ends[chosen] == goal).mean()) if chosen.any() else float("nan"),
            "message": messages[chosen].mean(axis=0) if chosen.any() else np.full(messages.shape[1], np.nan),  # type: ignore[union-attr]
            "message sd": float(messages[chosen].std(axis=0).max()) if chosen.any() else float("nan"),  # type: ignore[union-attr]
            "ends": [float((ends[chosen] == j).mean()) if chosen.any() else float("nan") for j in range(4)],
        })  # fmt: skip
    return rows


def buffer_rows(model: MADDPG, newest: int | None = None) -> np.ndarray:
    """The filled rows of the pack's replay buffer, oldest first (only the ``newest`` ones if given)."""
    buffer = model.replay_buffer
    if buffer is None:
        raise ValueError("the model has no replay buffer (a checkpoint folder's model has one)")
    size, pos = buffer.buffer_size, buffer.pos  # type: ignore[union-attr]
    rows = (np.arange(size) + pos) % size if buffer.full else np.arange(pos)  # type: ignore[union-attr]
    return rows if newest is None else rows[-newest:]


def on_buffer(model: MADDPG, k: int, candidates: np.ndarray, samples: int, seed: int, buffer: Any = None) -> dict[str, float]:
    """
    Run ``k``'s critics on ``samples`` transitions drawn from the buffer rows ``candidates`` of its own column of the
    pack's replay buffer (see the module docstring).

    :param buffer: Another pack's buffer of the same runs (a later checkpoint's; default: the model's own).
    """
    buffer = model.replay_buffer if buffer is None else buffer
    column = k * buffer.envs_per_run  # type: ignore[union-attr]
    rows = candidates[np.random.default_rng(seed).integers(0, len(candidates), size=samples)]
    # the bonus as a minibatch gets it (the pack's method asks for every run's rows: the same rows of their own columns)
    batch_inds = np.broadcast_to(rows, (model.n_runs, samples))
    env_inds = np.broadcast_to((np.arange(model.n_runs) * buffer.envs_per_run)[:, None], (model.n_runs, samples))  # type: ignore[union-attr]
    bonus = np.asarray(buffer._bonus(batch_inds, env_inds))  # type: ignore[union-attr]
    bonus = bonus[k] if bonus.ndim else bonus  # (samples, n_agents), or 0.0 without MACB
    rewards = buffer.agent_rewards[rows, column] + bonus  # type: ignore[union-attr]
    not_done = 1.0 - buffer.dones[rows, column] * (1.0 - buffer.timeouts[rows, column])  # type: ignore[union-attr]

    def pack(array: np.ndarray) -> th.Tensor:
        # the pack's networks take (n_runs, batch, dim): run k's rows in its slot, zeros (ignored) elsewhere
        out = th.zeros((model.n_runs, *array.shape), dtype=th.float32, device=model.device)
        out[k] = th.as_tensor(array, dtype=th.float32, device=model.device)
        return out

    obs = pack(buffer.observations[rows, column])  # type: ignore[union-attr]
    actions = pack(buffer.actions[rows, column])  # type: ignore[union-attr]
    next_obs = pack(buffer.next_observations[rows, column])  # type: ignore[union-attr]
    with th.no_grad():
        q = model.critic(obs, actions)[0, k].cpu().numpy()  # (n_agents, samples) of the first critic
        next_pi = model.actor_target(next_obs)
        next_q = model.critic_target(next_obs, next_pi)
        next_q = (next_q.min(dim=0).values if next_q.shape[0] > 1 else next_q[0])[k].cpu().numpy()
    td = q - (rewards.T + model.gamma * not_done * next_q)
    layout = model.agent_layout
    index = agent_index(layout, "listener")
    # the gap at s' between the target policy's actions (what the target bootstraps from) and the actions the run
    # took next (the following row of the same episode), by the target critic: all agents' actions, and the listener's
    following = (rows + 1) % buffer.buffer_size  # type: ignore[union-attr]
    continuing = np.isin(following, candidates) & (buffer.dones[rows, column] == 0) & np.all(  # type: ignore[union-attr]
        buffer.observations[following, column] == buffer.next_observations[rows, column], axis=-1)  # type: ignore[union-attr]
    taken = pack(buffer.actions[following[continuing], column])  # type: ignore[union-attr]
    continuing_t = th.as_tensor(continuing, device=model.device)
    with th.no_grad():
        s2 = next_obs[:, continuing_t]
        policy = next_pi[:, continuing_t]  # the target policy's actions at those s' (computed above)
        listener_only = taken.clone()
        listener_only[..., layout.action_slices[index]] = policy[..., layout.action_slices[index]]
        q_taken = model.critic_target(s2, taken)[0, k]
        gap = (model.critic_target(s2, policy)[0, k] - q_taken).mean(dim=-1).cpu().numpy()
        gap_listener = (model.critic_target(s2, listener_only)[0, k] - q_taken).mean(dim=-1).cpu().numpy()
    listener = buffer.observations[rows, column, layout.obs_slices[index]]  # type: ignore[union-attr]
    distances = landmark_distances(listener)
    # where episodes end (time limits): the states the target bootstraps from last, and how far the listener is there
    ending = buffer.timeouts[rows, column] == 1  # type: ignore[union-attr]
    listener_end = buffer.next_observations[rows[ending], column, layout.obs_slices[index]]  # type: ignore[union-attr]
    distances_end = landmark_distances(listener_end).min(axis=-1)
    out = {"lis dist": float(distances.min(axis=-1).mean()),
           "lis speed": float(np.linalg.norm(listener[:, :2], axis=-1).mean()),
           "r": float(rewards.mean()), "continuing": float(continuing.mean()),
           "lis dist end": float(distances_end.mean()) if ending.any() else float("nan")}  # fmt: skip
    for i, name in enumerate(layout.agents):  # type: ignore[union-attr]
        short = short_name(name)
        out[f"Q {short}"] = float(q[i].mean())
        out[f"TD {short}"] = float(td[i].mean())
        out[f"|TD| {short}"] = float(np.abs(td[i]).mean())
        out[f"gap {short}"] = float(gap[i])
        out[f"end {short}"] = float(next_q[i][ending].mean()) if ending.any() else float("nan")
        out[f"gap lis {short}"] = float(gap_listener[i])
    return out


def continue_from_checkpoint(folder: str, steps: int, preactivation_reg: float) -> MADDPG:
    """
    The pack of checkpoint ``folder`` trained ``steps`` more steps per run with ``preactivation_reg``, from the
    checkpoint's exact state (as ``Experiment`` resumes it, without its evaluation callback: nothing is written).
    """
    model, state = load_checkpoint(folder, allow_other_version=True, device="cpu")  # (a checkpoint this machine's runs wrote)
    if state.get("sb3_macb") != sb3_macb.__version__:
        print(f"note: {folder} was written by sb3_macb {state.get('sb3_macb')}, continued with {sb3_macb.__version__}")
    restore_global_rngs(state)
    model.preactivation_reg = float(preactivation_reg)
    model.learn(steps * model.n_runs, reset_num_timesteps=False)
    return model


def display_name(path: str) -> str:
    """A model's name in the tables: its file or folder name, or ``<variant>/<seed_s>`` for a run's final ``model.zip``."""
    path = os.path.normpath(path)
    if os.path.basename(path) == "model.zip":  # a finished run's model (or a checkpoint's): name it by its folders
        parts = os.path.dirname(path).split(os.sep)
        return "/".join(parts[-2:])
    return os.path.basename(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="+", help="model.zip files of packs (e.g. archived checkpoints)")
    parser.add_argument("--experiment", default=None, help="the pack's experiment.json (names the runs)")
    parser.add_argument("--task", choices=sorted(TASKS), default="comm-sparse",
                        help="the task of the models (nav: 2-Agent Navigation, the first table only)")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=12345)
    parser.add_argument("--continue-steps", type=int, default=0,
                        help="train checkpoint folders on for this many steps per run, then measure again")
    parser.add_argument("--preactivation-reg", type=float, nargs="+", default=[0.0],
                        help="preactivation_reg values for --continue-steps (one continuation each)")  # fmt: skip
    parser.add_argument("--per-goal", action="store_true",
                        help="also print, per goal landmark, the speaker's message and where the listener ends")  # fmt: skip
    parser.add_argument("--on-buffer", action="store_true",
                        help="also measure the critics on checkpoint folders' replay buffers (second table)")  # fmt: skip
    parser.add_argument("--buffer-of", default=None,
                        help="--on-buffer for earlier models (model.zip files) of a pack: each on the rows of this later "
                             "checkpoint folder's buffer that it had collected by its step")  # fmt: skip
    parser.add_argument("--recent", type=int, default=20_000, help="--on-buffer: the newest transitions per run")
    parser.add_argument("--samples", type=int, default=20_000, help="--on-buffer: transitions drawn per window")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    if args.continue_steps < 0:
        parser.error(f"--continue-steps must be at least 0, got {args.continue_steps}")
    if args.buffer_of and not (args.on_buffer and os.path.isfile(os.path.join(args.buffer_of, "state.pkl"))):
        parser.error(f"--buffer-of needs --on-buffer and a checkpoint folder, got {args.buffer_of}")
    if args.task != "comm-sparse" and (args.per_goal or args.on_buffer or args.continue_steps):
        parser.error(f"--task {args.task} measures the first table only: --per-goal, --on-buffer and --continue-steps "
                     "are Communicative Navigation's")  # fmt: skip
    if args.recent < 1 or args.samples < 1:
        parser.error(f"--recent and --samples must be at least 1, got {args.recent} and {args.samples}")
    for path in args.models:
        if not os.path.exists(path):
            parser.error(f"{path} does not exist")
        if (args.continue_steps or (args.on_buffer and not args.buffer_of)) \
                and not os.path.isfile(os.path.join(path, "state.pkl")):
            option = "--continue-steps" if args.continue_steps else "--on-buffer"
            parser.error(f"{option} needs checkpoint folders (model.zip, buffer.npz, state.pkl): {path} is not one")
    th.set_num_threads(1)

    def step_of(path: str) -> int:
        found = re.findall(r"\d+", os.path.basename(path))
        return int(found[-1]) if found else 0

    agents = ("spk", "lis") if args.task == "comm-sparse" else ("agent_0", "agent_1")
    columns = [f"{what} {agent}" for what in ("sat", "pre", "Q") for agent in agents]

    def rows(name: str, model: MADDPG) -> None:
        for k, (label, beta, constant) in enumerate(run_labels(args.experiment, model)):
            d = diagnose(model, k, beta, constant, args.episodes, args.seed, args.task)
            low, high = d["Q range"]  # type: ignore[misc]
            cells = [f"{d[c]:.1f}" if c.startswith("Q") else f"{d[c]:.2f}" for c in columns]
            print(f"| {name} | {label} | {d['any']:.2f} | {d['final']:.2f} | " + " | ".join(cells)
                  + f" | [{low:.0f}, {high:.0f}] | {d['Q out']:.2f} |", flush=True)  # fmt: skip

    print("| model | run | any | final | " + " | ".join(columns) + " | Q range | Q out |")
    print("|---|---|---|---|" + "---|" * len(columns) + "---|---|")
    for path in sorted(args.models, key=step_of):
        name = display_name(path)
        rows(name, MADDPG.load(os.path.join(path, "model.zip") if os.path.isdir(path) else path, device="cpu"))
        for reg in args.preactivation_reg if args.continue_steps else []:
            rows(f"{name} +{args.continue_steps} (reg {reg:g})", continue_from_checkpoint(path, args.continue_steps, reg))
    if args.per_goal:
        print()
        print("| model | run | goal | episodes | any | final | message (first step) | message sd "
              "| listener ends at landmark 0 / 1 / 2 / none |")
        print("|---|---|---|---|---|---|---|---|---|")
        for path in sorted(args.models, key=step_of):
            name = display_name(path)
            model = MADDPG.load(os.path.join(path, "model.zip") if os.path.isdir(path) else path, device="cpu")
            for k, (label, _beta, _constant) in enumerate(run_labels(args.experiment, model)):
                for row in per_goal(model, k, args.episodes, args.seed):
                    message = ", ".join(f"{v:.2f}" for v in row["message"])
                    ends = " / ".join(f"{v:.2f}" for v in row["ends"])
                    print(f"| {name} | {label} | {row['goal']} | {row['episodes']} | {row['any']:.2f} | {row['final']:.2f} | "
                          f"({message}) | {row['message sd']:.2f} | {ends} |", flush=True)  # fmt: skip
    if not args.on_buffer:
        return
    source = None
    if args.buffer_of:  # earlier models of the same pack, on the transitions they had collected by their step
        source, _ = load_checkpoint(args.buffer_of, allow_other_version=True, device="cpu")
        if source.replay_buffer.full:  # type: ignore[union-attr]
            raise SystemExit(f"{args.buffer_of}: its replay buffer has wrapped around; earlier models' rows are gone")
    print()
    print("| model | run | transitions | r | Q spk (s,a) | TD spk | abs TD spk | gap spk | gap(lis) spk | end spk "
          "| Q lis (s,a) "
          "| TD lis | abs TD lis | gap lis | gap(lis) lis | end lis | lis dist | lis speed | lis dist end |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(args.models, key=step_of):
        if source is None:
            model, _ = load_checkpoint(path, allow_other_version=True, device="cpu")
            buffer, everything = model.replay_buffer, buffer_rows(model)
        else:
            model = MADDPG.load(os.path.join(path, "model.zip") if os.path.isdir(path) else path, device="cpu")
            buffer = source.replay_buffer
            rows = model.num_timesteps // buffer.n_envs  # type: ignore[union-attr]
            if model.n_runs != source.n_runs or rows > buffer.pos:  # type: ignore[union-attr]
                raise SystemExit(f"{path} is not an earlier model of the pack of {args.buffer_of}")
            everything = np.arange(rows)
        newest = everything[-args.recent :]
        for k, (label, _beta, _constant) in enumerate(run_labels(args.experiment, model)):
            for window, candidates in ((f"all {len(everything)}", everything), (f"newest {len(newest)}", newest)):
                d = on_buffer(model, k, candidates, args.samples, args.seed, buffer)
                cells = [display_name(path), label, window, f"{d['r']:+.2f}"]
                for short in ("spk", "lis"):
                    cells += [f"{d[f'Q {short}']:.1f}", f"{d[f'TD {short}']:+.2f}", f"{d[f'|TD| {short}']:.2f}",
                              f"{d[f'gap {short}']:+.2f}", f"{d[f'gap lis {short}']:+.2f}",
                              f"{d[f'end {short}']:.1f}"]  # fmt: skip
                cells += [f"{d['lis dist']:.2f}", f"{d['lis speed']:.2f}", f"{d['lis dist end']:.2f}"]
                print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
