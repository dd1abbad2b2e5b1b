"""
How close a policy comes to success (a post-hoc diagnostic, not one of the registered metrics), over ``--episodes``
deterministic episodes of each run's final model; the scripted policy and random actions are measured alike, as
references.

- Sparse Spread: the mean number of landmarks covered (an agent within the task's cover radius) at the last step
  before the time limit, the share of episodes in which at least N - 1 landmarks are covered at some step, and the
  mean distance from a landmark to its nearest agent at that last step.
- Communicative Navigation (comm6-wide): the share of episodes in which the listener comes within the success radius
  of any landmark at some step (it navigates) and of the goal (it succeeds), and its mean distance to the nearest
  landmark and to the goal at the last step. A listener that reaches landmarks but not the goal navigates without
  the speaker's message.

    python scripts/coverage.py --task spread3 --results /path/to/results        # every run with a model.zip

Model zips are pickles: loading one runs code it names, so load only zips from a source you trust. The study's
model zips are not committed (they stay where the runs were made); the runs are deterministic, so running them
again remakes them.
"""

import argparse
import os
import sys

import numpy as np

STUDY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHECKOUT = os.path.dirname(os.path.dirname(STUDY))
sys.path[:0] = [p for p in (CHECKOUT, os.path.join(STUDY, "scripts")) if p not in sys.path[:2]]

from run_study import METHODS  # noqa: E402
from sb3_macb.envs.scripted import scripted_actions  # noqa: E402
from sb3_macb.envs.vec_spread import SpreadVecEnv  # noqa: E402
from sb3_macb.envs.vec_tasks import TaskVecEnv, make_task_vec_env  # noqa: E402
from study_tasks import CANDIDATES, EPISODE_STEPS  # noqa: E402

SPREAD_COLUMNS = {
    "covered_last": ("landmarks covered at the last step", "{:.2f}"),
    "near_success": ("episodes with >= N-1 covered at some step", "{:.3f}"),
    "distance_last": ("nearest-agent distance at the last step", "{:.3f}"),
}
LISTENER_COLUMNS = {
    "any_landmark": ("episodes with the listener at some landmark", "{:.3f}"),
    "goal": ("episodes with the listener at the goal", "{:.3f}"),
    "landmark_distance_last": ("listener to nearest landmark, last step", "{:.3f}"),
    "goal_distance_last": ("listener to goal, last step", "{:.3f}"),
}


def coverage(task: str, act, episodes: int, seed: int) -> dict[str, float]:
    """
    Coverage statistics of a policy on a Sparse Spread task, all episodes side by side.

    :param task: A Sparse Spread key of ``CANDIDATES``.
    :param act: A function of (observations, the SpreadVecEnv) returning joint actions.
    :param episodes: Number of episodes.
    :param seed: Seed of the envs.
    :return: ``covered_last`` (mean landmarks covered at the last step before the time limit), ``near_success``
        (share of episodes with at least N - 1 covered at some step), ``distance_last`` (mean nearest-agent distance
        of a landmark at that step).
    """
    env_id, env_kwargs = CANDIDATES[task]
    venv = make_task_vec_env(env_id, episodes, env_kwargs)
    inner = venv.unwrapped
    if not isinstance(inner, SpreadVecEnv):
        raise SystemExit(f"--task: {task} is not a Sparse Spread task")
    venv.seed(seed)
    obs = venv.reset()
    n = inner.n_agents
    best = np.zeros(episodes, dtype=np.int64)
    for _ in range(EPISODE_STEPS[task] - 1):  # the last step resets the envs, so stop one short of it
        obs, _, _, _ = venv.step(act(obs, inner))
        agents, landmarks = inner.pos[:, :n], inner.pos[:, n:]
        nearest = np.linalg.norm(landmarks[:, :, None, :] - agents[:, None, :, :], axis=-1).min(axis=2)
        covered = (nearest <= inner.cover_radius).sum(axis=1)
        best = np.maximum(best, covered)
    venv.close()
    return {"covered_last": float(covered.mean()), "near_success": float(np.mean(best >= n - 1)),
            "distance_last": float(nearest.mean())}  # fmt: skip


def listener_reach(task: str, act, episodes: int, seed: int) -> dict[str, float]:
    """
    Where a Communicative Navigation policy takes the listener, all episodes side by side.

    :param task: A Communicative Navigation key of ``CANDIDATES``.
    :param act: A function of (observations, the TaskVecEnv) returning joint actions.
    :param episodes: Number of episodes.
    :param seed: Seed of the envs.
    :return: ``any_landmark`` and ``goal`` (shares of episodes with the listener within the success radius of any
        landmark, of the goal, at some step), ``landmark_distance_last`` and ``goal_distance_last`` (its mean
        distance to the nearest landmark and to the goal at the last step before the time limit).
    """
    env_id, env_kwargs = CANDIDATES[task]
    venv = make_task_vec_env(env_id, episodes, env_kwargs)
    inner = venv.unwrapped
    if not isinstance(inner, TaskVecEnv) or inner.task != "communication":
        raise SystemExit(f"--task: {task} is not a Communicative Navigation task")
    venv.seed(seed)
    obs = venv.reset()
    rows = np.arange(episodes)
    at_landmark, at_goal = np.zeros(episodes, dtype=bool), np.zeros(episodes, dtype=bool)
    for _ in range(EPISODE_STEPS[task] - 1):  # the last step resets the envs, so stop one short of it
        obs, _, _, _ = venv.step(act(obs, inner))
        listener, landmarks = inner.pos[:, 1], inner.pos[:, 2:]
        distances = np.linalg.norm(landmarks - listener[:, None, :], axis=-1)
        nearest, to_goal = distances.min(axis=1), distances[rows, inner.goal]
        at_landmark |= nearest <= inner.success_radius
        at_goal |= to_goal <= inner.success_radius
    venv.close()
    return {"any_landmark": float(at_landmark.mean()), "goal": float(at_goal.mean()),
            "landmark_distance_last": float(nearest.mean()), "goal_distance_last": float(to_goal.mean())}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", required=True, choices=[t for t in CANDIDATES if t.startswith(("spread", "comm"))])
    parser.add_argument("--results", required=True, help="the folder the runs were filed in, with their model.zip")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1000, help="seed of the envs (default: not a training seed)")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    from sb3_macb import MADDPG

    rng = np.random.default_rng(args.seed)
    references = {
        "scripted": lambda obs, env: scripted_actions(env),
        "random actions": lambda obs, env: rng.uniform(
            env.action_space.low, env.action_space.high, size=(env.num_envs, *env.action_space.shape)
        ),
    }
    measure, columns = (coverage, SPREAD_COLUMNS) if args.task.startswith("spread") else (listener_reach, LISTENER_COLUMNS)
    first = next(iter(columns))
    print(f"{args.task}, {args.episodes} episodes (env seed {args.seed}), deterministic policies")
    print(f"| policy | {columns[first][0]} (mean over seeds; per seed) | "
          + " | ".join(title for title, _ in list(columns.values())[1:]) + " |")  # fmt: skip
    print("|---" * (len(columns) + 1) + "|")

    def row(name: str, results: list[dict[str, float]]) -> str:
        mean = {key: np.mean([r[key] for r in results]) for key in columns}
        cells = [columns[key][1].format(mean[key]) for key in columns]
        if len(results) > 1:
            cells[0] += " (" + ", ".join(columns[first][1].format(r[first]) for r in results) + ")"
        return f"| {name} | " + " | ".join(cells) + " |"

    for name, act in references.items():
        print(row(name, [measure(args.task, act, args.episodes, args.seed)]))
    for method in METHODS:
        results = []
        for seed in range(5):
            path = os.path.join(args.results, args.task, method, f"seed_{seed}", "model.zip")
            if os.path.isfile(path):
                model = MADDPG.load(path, device="cpu")
                results.append(measure(args.task, lambda obs, env, m=model: m.predict(obs, deterministic=True)[0],
                                       args.episodes, args.seed))  # fmt: skip
        if results:
            print(row(f"{method} ({len(results)} seeds)", results))


if __name__ == "__main__":
    main()
