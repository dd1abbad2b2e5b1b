"""The run axis of a MADDPG model: what each run of a pack owns, and how a pack's counts relate to a run's."""

import copy
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.noise import ActionNoise, VectorizedActionNoise

from sb3_macb.envs.joint_env import AgentLayout
from sb3_macb.exploration.estimators import make_exploration
from sb3_macb.exploration.macb import MACB
from sb3_macb.exploration.rnd import RND

Exploration = MACB | RND
ExplorationSetting = MACB | RND | dict[str, Any] | None


class Pack:
    """
    The runs of a MADDPG model (``n_runs=K``; an ordinary model is a pack of one). Each run owns its seed, its random
    generator (warm-up actions, action noise, minibatches, target-policy and Gumbel noise) and its exploration
    (an MACB or RND with its own hash matrix and count table, or None). A pack owns them all, in run order; the
    model, its replay buffer and its callbacks read them here.

    The envs of a VecEnv are split between the runs in order: env ``e`` belongs to run ``e // envs_per_run``.
    SB3 counts steps over all envs (``num_timesteps``, ``learn(total_timesteps)``, ``learning_starts``):
    :meth:`run_steps` and :meth:`pack_steps` convert between such counts and a run's own.

    :param n_runs: Number of runs, >= 1.
    :param seeds: One seed per run, or None (unseeded runs).
    :param exploration: The runs' exploration: an MACB or RND, a dict of its arguments, or None, for every run (each
        run gets its own copy), or a list of one per run (an object that appears more than once is copied, so that
        every run has its own hash matrix and count table).
    :param seed: Without ``seeds``: run ``k`` is seeded ``seed + k`` (None: unseeded runs).
    """

    def __init__(
        self,
        n_runs: int = 1,
        seeds: list[int] | None = None,
        exploration: "ExplorationSetting | list[ExplorationSetting]" = None,
        seed: int | None = None,
    ):
        if isinstance(n_runs, bool) or not isinstance(n_runs, (int, np.integer)) or n_runs < 1:
            raise ValueError(f"n_runs must be an integer >= 1, got {n_runs!r}")
        if seeds is not None and len(seeds) != n_runs:
            raise ValueError(f"run_seeds needs one seed per run ({n_runs}), got {seeds}")
        if seeds is None and seed is not None:
            seeds = [int(seed) + k for k in range(n_runs)]
        if isinstance(exploration, (list, tuple)):
            per_run, seen = [], set()
            for setting in exploration:
                per_run.append(copy.deepcopy(setting) if isinstance(setting, (MACB, RND)) and id(setting) in seen else setting)
                seen.add(id(setting))
        else:
            per_run = [exploration] + [copy.deepcopy(exploration) for _ in range(n_runs - 1)]
        if len(per_run) != n_runs:
            raise ValueError(f"exploration: expected one setting per run ({n_runs}), got {len(per_run)}")
        self.n_runs = int(n_runs)
        self.seeds = None if seeds is None else [int(seed) for seed in seeds]
        self.explorations: list[Exploration | None] = [make_exploration(setting) for setting in per_run]
        self.rngs: list[np.random.Generator] | None = None  # made by setup (a loaded model brings their states)

    def __repr__(self) -> str:
        return f"Pack(n_runs={self.n_runs}, seeds={self.seeds})"

    # --- step counts -------------------------------------------------------------------------------------------------

    def run_steps(self, steps: int) -> int:
        """One run's share of ``steps`` counted over all the pack's envs (``num_timesteps // n_runs``)."""
        return int(steps) // self.n_runs

    def pack_steps(self, run_steps: int) -> int:
        """The count over all the pack's envs for ``run_steps`` steps of every run (``run_steps * n_runs``)."""
        return int(run_steps) * self.n_runs

    # --- envs ------------------------------------------------------------------------------------------------------

    def envs_per_run(self, n_envs: int) -> int:
        """How many of ``n_envs`` envs each run steps; a clear ValueError when they cannot be split evenly."""
        if n_envs % self.n_runs:
            raise ValueError(f"A pack of {self.n_runs} runs needs a number of envs divisible by {self.n_runs}, got {n_envs}")
        return n_envs // self.n_runs

    def env_seeds(self, n_envs: int) -> list[int] | None:
        """The seed of each env: env ``j`` of run ``k`` is seeded ``seeds[k] + j`` (None for unseeded runs)."""
        if self.seeds is None:
            return None
        step = self.envs_per_run(n_envs)
        return [self.seeds[e // step] + e % step for e in range(n_envs)]

    def env_rngs(self, n_envs: int) -> list[np.random.Generator]:
        """The generator of each env's run (run ``k``'s envs all draw from run ``k``'s generator, in env order)."""
        assert self.rngs is not None, "the pack is not set up"
        step = self.envs_per_run(n_envs)
        return [self.rngs[e // step] for e in range(n_envs)]

    def env_noise(self, run_noises: list[ActionNoise], n_envs: int) -> ActionNoise:
        """One action noise process per env, run ``k``'s envs each with a copy of ``run_noises[k]``."""
        step = self.envs_per_run(n_envs)
        per_env = [copy.deepcopy(run_noises[e // step]) for e in range(n_envs)]
        if n_envs == 1:
            return per_env[0]
        vectorized = VectorizedActionNoise(per_env[0], n_envs)
        vectorized.noises = per_env
        return vectorized

    def run_noise(self, noise: ActionNoise, k: int, n_envs: int) -> ActionNoise:
        """A copy of run ``k``'s action noise (its first env's process) from the model's noise over ``n_envs`` envs."""
        if isinstance(noise, VectorizedActionNoise):
            noise = noise.noises[k * self.envs_per_run(n_envs)]
        return copy.deepcopy(noise)

    # --- random streams and explorations ---------------------------------------------------------------------------

    @property
    def explores(self) -> bool:
        """Whether any run has an exploration."""
        return any(e is not None for e in self.explorations)

    def setup(self, layout: AgentLayout) -> None:
        """Set every run's exploration up for the agents of ``layout`` with its run's seed, and make the runs'
        generators (``np.random.default_rng(seed)``) unless they exist (a loaded model brings their states)."""
        seeds: list[int | None] = list(self.seeds) if self.seeds is not None else [None] * self.n_runs
        for exploration, seed in zip(self.explorations, seeds):
            if exploration is not None:
                exploration.setup(layout, seed=seed)
        if self.rngs is None:
            self.rngs = [np.random.default_rng(seed) for seed in seeds]

    def draws(self, distribution: str, shape: tuple[int, ...], device: th.device | str = "cpu") -> th.Tensor:
        """
        One float32 array of ``shape`` per run from that run's own generator (``distribution``: a method of
        ``np.random.Generator``), stacked to ``(n_runs, *shape)`` on ``device``: a packed run draws what its solo
        run draws.
        """
        assert self.rngs is not None, "the pack is not set up"
        values = np.stack([getattr(rng, distribution)(size=shape) for rng in self.rngs])
        return th.as_tensor(values, dtype=th.float32, device=device)

    def run(self, k: int, layout: AgentLayout | None = None) -> "Pack":
        """
        Run ``k`` as a pack of one: copies of its seed, its generator's state and its exploration.

        :param k: The run, 0 to ``n_runs - 1``.
        :param layout: The agents' layout the explorations were set up for: the copy is set up for it and takes the
            run's hash matrices and count tables (None: a copy of the settings only).
        """
        if not 0 <= k < self.n_runs:
            raise IndexError(f"run {k} out of range for a pack of {self.n_runs}")
        seeds = None if self.seeds is None else [self.seeds[k]]
        exploration = self.explorations[k]
        clone = copy.deepcopy(exploration)  # (settings only: pickling leaves the matrices and tables out)
        solo = Pack(1, seeds, [clone])
        solo.rngs = None if self.rngs is None else [copy.deepcopy(self.rngs[k])]
        if layout is not None and exploration is not None and clone is not None and exploration.is_setup:
            clone.setup(layout, seed=None if seeds is None else seeds[0])
            clone.load_state_dict(exploration.state_dict())
        return solo

    def state_dict(self) -> dict[str, th.Tensor]:
        """The explorations' states (hash matrices, count tables, normalizers), run ``k``'s keys prefixed ``run{k}.``."""
        return {
            f"run{k}.{name}": tensor
            for k, exploration in enumerate(self.explorations)
            if exploration is not None
            for name, tensor in exploration.state_dict().items()
        }

    def load_state_dict(self, state: dict[str, th.Tensor], strict: bool = True) -> None:
        """Load the states that :meth:`state_dict` gave into the runs' (set-up) explorations."""
        for k, exploration in enumerate(self.explorations):
            if exploration is not None:
                prefix = f"run{k}."
                exploration.load_state_dict({key[len(prefix) :]: v for key, v in state.items() if key.startswith(prefix)})
