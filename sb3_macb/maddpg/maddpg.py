import copy
import inspect
import io
import os
import pathlib
import warnings
from collections.abc import Iterable
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import (
    ActionNoise,
    NormalActionNoise,
    OrnsteinUhlenbeckActionNoise,
    VectorizedActionNoise,
)
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule, TrainFreq, TrainFrequencyUnit
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.td3 import TD3

from sb3_macb.buffers import MACBReplayBuffer, MultiAgentReplayBuffer, RunSamples
from sb3_macb.common.atomic import atomic_write, with_suffix
from sb3_macb.common.private_apis import lerp_, set_next_reset_seeds
from sb3_macb.envs.joint_env import AgentLayout, is_pettingzoo_env, make_joint_env
from sb3_macb.exploration.macb import MACB
from sb3_macb.exploration.rnd import RND
from sb3_macb.maddpg.pack import Pack
from sb3_macb.maddpg.policies import MADDPGPolicy, MlpPolicy, MultiAgentActor, MultiAgentCritic, _block_mask

SelfMADDPG = TypeVar("SelfMADDPG", bound="MADDPG")


def flushing_denormals() -> bool:
    """Whether this thread's CPU arithmetic flushes denormal floats to zero (``torch.set_flush_denormal`` has no getter)."""
    return float((th.tensor([1e-39], dtype=th.float32) * 1.0).item()) == 0.0


# weight of the discrete agents' mean squared logits in the actor loss (the MADDPG paper's and code's 1e-3)
DISCRETE_LOGIT_PENALTY = 1e-3
# above this chance that a code never seen is counted as seen, a count-min MACB warns that its sketch is too narrow
SKETCH_SATURATED = 0.1


class MADDPG(TD3):
    """
    Multi-Agent Deep Deterministic Policy Gradient (MADDPG): one deterministic actor per agent on its own
    observation, one centralized critic per agent on all agents' observations and actions, each critic
    learning from its own agent's reward.

    Paper: https://arxiv.org/abs/1706.02275

    The environment is a joint env (:func:`sb3_macb.make_joint_env`); a PettingZoo ``ParallelEnv`` or ``AECEnv``
    passed directly is wrapped the same way. All agents' networks are held as stacked tensors and trained in
    one batched pass. With ``centralized_critic=False`` every critic sees only its own agent (independent
    DDPG learners); with ``policy_kwargs=dict(n_critics=2)``, ``policy_delay=2`` and ``target_policy_noise=0.2``
    it is MATD3. With ``exploration=MACB(...)`` the replay buffer adds MACB's count-based bonus to sampled rewards.

    **Packs.** With ``n_runs=K`` the model trains K independent runs at once, in one process and one set of
    stacked tensors: the VecEnv's envs are split between the runs in order (one env per run is usual), every run
    has its own networks, optimizer state (Adam is element-wise), minibatches, action noise, MACB count table and
    random streams (``run_seeds``), and ``get_run(k)`` hands run ``k`` out as an ordinary model. Step counts
    (``total_timesteps``, ``learning_starts``, ``num_timesteps``) are, as everywhere in SB3, summed over all envs:
    K runs of T steps each are ``learn(K * T)``. ``buffer_size`` and ``gradient_steps=-1`` are per run: each run
    keeps ``buffer_size`` transitions and does as many updates as a solo run. Run ``k`` is the same experiment as a
    model with ``n_runs=1`` and ``seed=run_seeds[k]`` (bit for bit on CPU's oneDNN path, see the tests).

    :param policy: The policy model to use (``"MlpPolicy"``).
    :param env: The environment to learn from: a joint env, a PettingZoo env, or a registered env id.
    :param learning_rate: Learning rate for Adam (actors and critics); can be a schedule.
    :param buffer_size: Transitions the replay buffer keeps, of each run in a pack.
    :param learning_starts: How many steps to collect transitions for before learning starts.
    :param batch_size: Minibatch size for each gradient update (one minibatch, the same indices, for all agents).
    :param tau: The soft update coefficient ("Polyak update", between 0 and 1).
    :param gamma: The discount factor.
    :param train_freq: Update the model every ``train_freq`` steps, or a tuple like ``(5, "step")``.
    :param gradient_steps: How many gradient steps to do after each rollout (-1: as many as env steps of one run).
    :param action_noise: The action noise (e.g. ``NormalActionNoise`` over the joint action dimension).
    :param replay_buffer_class: Replay buffer class; must derive from :class:`MultiAgentReplayBuffer`.
    :param replay_buffer_kwargs: Keyword arguments to pass to the replay buffer on creation.
    :param optimize_memory_usage: SB3's memory efficient replay buffer variant.
    :param policy_delay: Update the actors and target networks every ``policy_delay`` critic updates.
    :param target_policy_noise: Standard deviation of the target policy smoothing noise (0: plain MADDPG).
    :param target_noise_clip: Limit for the absolute value of the target policy smoothing noise.
    :param centralized_critic: Whether each agent's critic sees all agents (MADDPG) or only its own agent's
        observation and action (independent DDPG learners).
    :param exploration: Count-based exploration: an :class:`~sb3_macb.MACB`, a dict of its arguments, or None.
        For a pack, one of these for every run, or a list of one per run; an MACB object that appears more than
        once in the list is copied, so that every run has its own hash matrix and count table.
    :param stats_window_size: Window size for the rollout logging.
    :param tensorboard_log: The log location for tensorboard (if None, no logging).
    :param policy_kwargs: Additional arguments for the policy (``net_arch``, ``n_critics``, ...).
    :param verbose: Verbosity level: 0 none, 1 info, 2 debug.
    :param seed: Seed for the pseudo random generators.
    :param device: Device (cpu, cuda, ...) on which the code should be run.
    :param n_runs: Independent runs trained together (a pack); 1 for an ordinary model.
    :param run_seeds: Seed of each run (networks, action noise, random warm-up actions, minibatches, env seeds,
        MACB's hash matrix). Default: ``seed + k`` for run ``k`` when ``seed`` is given.
    :param share_parameters: Agents that share one actor: ``"all"``, ``"prefix"`` (names equal up to the last
        ``_``, as mpe2's ``adversary_*``/``agent_*``), or lists of agent names; None: every agent has its own. Agents of
        a group need equal observation and action spaces; a shared actor reads the agent's observation followed by
        its one-hot id within the group.
    :param share_critics: Share the (centralized) critics in the same groups, each critic input with the agent's id;
        each agent's critic still learns from its own reward.
    :param flush_denormal: During ``learn``, flush denormal floats (below 1.2e-38) to zero on CPU, as
        ``torch.set_flush_denormal(True)`` does, and restore the previous setting afterwards. Adam's moments of
        units whose gradient is zero (dead ReLUs) decay into the denormal range after some 10^4-10^5 updates, and
        arithmetic on denormals is 10-100 times slower on many CPUs (Intel's in particular): on an Intel Xeon the
        400-300 pack of three trained 1.7 times faster with flushing from step ~60,000 on. Values that small do not
        change what is learned, but a run with flushing is not bit-identical to one without. The setting holds for
        the calling thread (torch's intra-op threads keep their own); with one torch thread it covers all of training.
    :param preactivation_reg: Weight of the mean squared pre-``tanh`` output of the continuous actors in the actor
        loss, as the original MADDPG code adds (1e-3 there); 0 (the default) leaves the loss as it is. A continuous
        actor whose critic keeps asking for more than the bound drives its outputs deep into ``tanh``'s flat part:
        its gradient through ``tanh`` vanishes but Adam rescales it, so the outputs keep growing, and the action
        stays at the bound (the paper study, experiments/macb_paper/README.md, shows this in the 400-300 runs with a
        reward offset). The penalty pulls the outputs back; it does not change a critic that asks for the bound, so
        it need not revive such a run.
        Discrete agents' logits always get ``DISCRETE_LOGIT_PENALTY`` (1e-3), as in the MADDPG paper.
    :param intrinsic_critic: Learn the exploration bonus with critics of its own (``critic_int``): the critics
        learn the reward alone, the intrinsic critics learn ``bonus + intrinsic_gamma * Q_int(s', pi'(s'))`` with no
        episode-end masking (novelty does not end with an episode), and each actor ascends
        ``Q + intrinsic_coef * Q_int``. The bonus then never enters the reward, so it adds no offset to the critics'
        values. Needs an exploration setting. Works with MATD3's settings (the smaller target of the intrinsic
        critics too), sharing and packs.
    :param intrinsic_gamma: Discount of the intrinsic critics.
    :param intrinsic_coef: Weight of the intrinsic critics' value in the actors' objective.
    :param _init_setup_model: Whether or not to build the network at the creation of the instance.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    # the constructor's settings a run of a pack keeps as it is when handed out (get_run), held under their own names
    _RUN_SETTINGS: ClassVar[tuple[str, ...]] = (
        "learning_rate",
        "buffer_size",
        "batch_size",
        "tau",
        "gamma",
        "train_freq",
        "gradient_steps",
        "replay_buffer_kwargs",
        "optimize_memory_usage",
        "policy_delay",
        "target_policy_noise",
        "target_noise_clip",
        "centralized_critic",
        "tensorboard_log",
        "policy_kwargs",
        "verbose",
        "share_parameters",
        "share_critics",
        "flush_denormal",
        "preactivation_reg",
        "intrinsic_critic",
        "intrinsic_gamma",
        "intrinsic_coef",
    )
    # (narrower than TD3's types: MADDPG's networks are its own classes)
    policy: MADDPGPolicy  # type: ignore[assignment]
    actor: MultiAgentActor  # type: ignore[assignment]
    actor_target: MultiAgentActor  # type: ignore[assignment]
    critic: MultiAgentCritic  # type: ignore[assignment]
    critic_target: MultiAgentCritic  # type: ignore[assignment]
    replay_buffer: MultiAgentReplayBuffer
    #: The runs of the model (seeds, random generators, explorations) and the step arithmetic between them.
    pack: Pack

    def __init__(
        self,
        policy: str | type[MADDPGPolicy],
        env: GymEnv | str | Any,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | list[ActionNoise] | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        policy_delay: int = 1,
        target_policy_noise: float = 0.0,
        target_noise_clip: float = 0.5,
        centralized_critic: bool = True,
        exploration: MACB | RND | dict[str, Any] | list[MACB | RND | dict[str, Any] | None] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        n_runs: int = 1,
        run_seeds: list[int] | None = None,
        share_parameters: str | list[list[str]] | None = None,
        share_critics: bool = False,
        flush_denormal: bool = True,
        preactivation_reg: float = 0.0,
        intrinsic_critic: bool = False,
        intrinsic_gamma: float = 0.99,
        intrinsic_coef: float = 1.0,
        _init_setup_model: bool = True,
    ):
        if (
            isinstance(preactivation_reg, bool)
            or not isinstance(preactivation_reg, (int, float, np.floating, np.integer))
            or not np.isfinite(preactivation_reg)
            or preactivation_reg < 0
        ):
            raise ValueError(f"preactivation_reg must be a finite number >= 0, got {preactivation_reg!r}")
        for name, value, low, high in (
            ("intrinsic_gamma", intrinsic_gamma, 0.0, 1.0),
            ("intrinsic_coef", intrinsic_coef, 0.0, None),
        ):
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float, np.floating, np.integer))
                or not np.isfinite(value)
                or value < low
                or (high is not None and value > high)
            ):
                raise ValueError(f"{name} must be a number in [{low}, {high if high is not None else 'inf'}), got {value!r}")
        if policy_kwargs and (
            {"agent_layout", "centralized_critic", "share_actors", "share_critics", "intrinsic_critic"} & set(policy_kwargs)
        ):
            raise ValueError(
                "Pass centralized_critic to MADDPG itself (and share_parameters, share_critics), not in policy_kwargs; "
                "the agent layout is read from the env"
            )
        if replay_buffer_class is not None and not issubclass(replay_buffer_class, MultiAgentReplayBuffer):
            raise TypeError(
                f"replay_buffer_class must derive from sb3_macb.buffers.MultiAgentReplayBuffer, got {replay_buffer_class}"
            )
        self.pack = Pack(n_runs, run_seeds, exploration, seed=seed)
        if seed is None and self.pack.seeds is not None:
            seed = self.pack.seeds[0]
        self.agent_layout: AgentLayout | None = None
        self.centralized_critic = centralized_critic
        if not (
            share_parameters is None or share_parameters in ("all", "prefix") or isinstance(share_parameters, (list, tuple))
        ):
            raise ValueError(
                f"share_parameters must be None, 'all', 'prefix' or a list of lists of agent names, got {share_parameters!r}"
            )
        if share_critics and share_parameters is None:
            raise ValueError("share_critics=True shares critics in the groups of share_parameters: give share_parameters too")
        if share_critics and not centralized_critic:
            raise ValueError("Critics can be shared only when they are centralized (centralized_critic=True)")
        self.share_parameters = (
            [list(g) for g in share_parameters] if isinstance(share_parameters, (list, tuple)) else share_parameters
        )
        self.share_critics = bool(share_critics)
        if intrinsic_critic and not self.pack.explores:
            raise ValueError("intrinsic_critic=True learns an exploration bonus: give exploration=MACB(...) too")
        self.intrinsic_critic = bool(intrinsic_critic)
        self.intrinsic_gamma = float(intrinsic_gamma)
        self.intrinsic_coef = float(intrinsic_coef)
        if isinstance(action_noise, (list, tuple)) and len(action_noise) != n_runs:
            raise ValueError(f"action_noise: expected one per run ({n_runs}), got {len(action_noise)}")
        # (the pack, with its explorations' settings, travels in the saved data; their matrices and count tables
        # as a state dict)
        run_noises: list[ActionNoise] | None = None
        first_noise: ActionNoise | None
        if isinstance(action_noise, (list, tuple)):
            run_noises = list(action_noise)
            first_noise = run_noises[0]
        else:
            first_noise = action_noise
        super().__init__(
            policy,  # type: ignore[arg-type]  # (a MADDPGPolicy, not a TD3Policy)
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=first_noise,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            policy_delay=policy_delay,
            target_policy_noise=target_policy_noise,
            target_noise_clip=target_noise_clip,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.flush_denormal = flush_denormal
        self.preactivation_reg = float(preactivation_reg)
        if run_noises is not None and self.env is not None:
            self.action_noise = self.pack.env_noise(run_noises, self.n_envs)
        if _init_setup_model:
            self._setup_model()

    # --- runs of a pack -------------------------------------------------------------------------------------------

    @property
    def n_runs(self) -> int:
        """The number of runs trained together (1 for an ordinary model)."""
        return self.pack.n_runs

    @property
    def run_seeds(self) -> list[int] | None:
        """The seed of each run (None: unseeded)."""
        return self.pack.seeds

    @property
    def explorations(self) -> list[MACB | RND | None]:
        """The exploration of each run (None where a run has none), owned by :attr:`pack`."""
        return self.pack.explorations

    @property
    def exploration(self) -> MACB | RND | None:
        """The exploration of an ordinary model (None without one); packs have one per run in ``explorations``."""
        if self.n_runs != 1:
            raise AttributeError("A pack has one MACB per run: use model.explorations[k] (or model.get_run(k).exploration)")
        return self.pack.explorations[0]

    @property
    def _exploration_pack(self) -> Pack:
        # the name under which a pack's exploration states are saved in the model's zip (as in sb3_macb <= 0.12)
        return self.pack

    @property
    def run_timesteps(self) -> int:
        """Steps of each run so far (``num_timesteps``, which SB3 counts over all envs, divided between the runs)."""
        return self.pack.run_steps(self.num_timesteps)

    @property
    def envs_per_run(self) -> int:
        """How many envs each run steps."""
        return self.pack.envs_per_run(self.n_envs)

    def set_random_seed(self, seed: int | None = None) -> None:
        """
        Seed the global generators (python, numpy, torch) and the env as SB3 does; in a pack, env ``j`` of run
        ``k`` is seeded ``run_seeds[k] + j`` (for one run, ``seed + j`` as SB3 seeds it).
        """
        super().set_random_seed(seed)
        venv = self.env
        seeds = None if venv is None else self.pack.env_seeds(self.n_envs)
        if venv is not None and seeds is not None:
            while isinstance(venv, VecEnvWrapper):
                venv = venv.venv
            set_next_reset_seeds(venv, seeds)  # one seed per env instead of seed + index

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        SB3's action sampling (random warm-up actions, then the actors' actions plus noise, clipped to the bounds),
        with every random draw made by the env's run's own generator.
        """
        rngs = self.pack.env_rngs(n_envs)
        discrete = self._discrete_mask
        if self.num_timesteps < learning_starts:
            low, high = self.action_space.low, self.action_space.high  # type: ignore[attr-defined]
            unscaled = np.stack([rng.uniform(low, high) for rng in rngs]).astype(np.float32)
            if discrete is not None:  # a discrete agent's warm-up action: one-hot of a uniform random choice
                unscaled = self._one_hot(unscaled)
        else:
            assert self._last_obs is not None, "self._last_obs was not set"
            gumbel = None
            if discrete is not None:  # discrete agents explore by sampling their policy (Gumbel-max)
                dim = self.agent_layout.action_dim  # type: ignore[union-attr]
                gumbel = th.as_tensor(np.stack([rng.gumbel(size=dim) for rng in rngs]),
                                      dtype=th.float32, device=self.device)  # fmt: skip
            unscaled = self._actor_actions(self._last_obs, gumbel)  # type: ignore[arg-type]
        scaled = self.policy.scale_action(unscaled)
        if action_noise is not None:
            noise = self._draw_noise(action_noise, rngs)
            if discrete is not None:
                noise[:, discrete] = 0.0  # action noise is for continuous agents
            scaled = np.clip(scaled + noise, -1, 1)
        return self.policy.unscale_action(scaled), scaled

    def _actor_actions(self, observations: np.ndarray, gumbel: th.Tensor | None = None) -> np.ndarray:
        """
        The actors' actions in the env's bounds for a batch of joint observations, as ``predict`` returns them for a
        VecEnv's Box observations (MADDPG's actors are deterministic), without its checks and conversions per call.

        :param observations: (n_envs, obs_dim), for a pack the runs' envs one run after another.
        :param gumbel: Gumbel noise for discrete agents' sampled actions (None: their greedy actions).
        """
        self.policy.set_training_mode(False)
        with th.no_grad():
            obs = th.as_tensor(observations, device=self.device).float()
            return self.policy.unscale_action(self.actor(obs, gumbel=gumbel).cpu().numpy())

    def _one_hot(self, actions: np.ndarray) -> np.ndarray:
        """(n, action_dim) actions in the env's bounds with each discrete agent's slice made one-hot at its argmax."""
        result = actions.copy()
        layout = self.agent_layout
        assert layout is not None
        for sl, flag in zip(layout.action_slices, layout.discrete_agents):
            if flag:
                block = np.zeros_like(result[:, sl])
                block[np.arange(len(block)), result[:, sl].argmax(axis=1)] = 1.0
                result[:, sl] = block
        return result

    def _draw_noise(self, action_noise: ActionNoise, rngs: list[np.random.Generator]) -> np.ndarray:
        """
        One noise vector per env, Gaussian and Ornstein-Uhlenbeck noise drawn from the env's run's generator.

        :param action_noise: The model's noise (one process per env, or one for the single env).
        :param rngs: Each env's run's generator (:meth:`Pack.env_rngs`).
        """
        noises = action_noise.noises if isinstance(action_noise, VectorizedActionNoise) else [action_noise] * len(rngs)
        draws = []
        for rng, noise in zip(rngs, noises):
            if isinstance(noise, NormalActionNoise):
                draws.append(rng.normal(noise._mu, noise._sigma))
            elif isinstance(noise, OrnsteinUhlenbeckActionNoise):
                x = (
                    noise.noise_prev
                    + noise._theta * (noise._mu - noise.noise_prev) * noise._dt
                    + noise._sigma * np.sqrt(noise._dt) * rng.normal(size=noise._mu.shape)
                )
                noise.noise_prev = x
                draws.append(x)
            else:  # another noise class: its own random source
                draws.append(noise())
        return np.asarray(draws, dtype=np.float32)

    @staticmethod
    def _wrap_env(env: GymEnv | Any, verbose: int = 0, monitor_wrapper: bool = True) -> VecEnv:
        if is_pettingzoo_env(env):
            env = make_joint_env(env)
        return OffPolicyAlgorithm._wrap_env(env, verbose, monitor_wrapper)

    @staticmethod
    def _env_layout(env: VecEnv) -> AgentLayout:
        try:
            layouts = env.get_attr("agent_layout")
        except AttributeError:
            layouts = [None]
        if not isinstance(layouts[0], AgentLayout):
            raise TypeError(
                "MADDPG needs a multi-agent env: pass a PettingZoo env, or a gymnasium env made with "
                "sb3_macb.make_joint_env (it has no 'agent_layout' attribute)."
            )
        return layouts[0]

    def _check_layout(self, env: VecEnv) -> None:
        layout = self._env_layout(env)
        if self.agent_layout is not None and layout != self.agent_layout:
            raise ValueError(
                f"The env's agents do not match the model's: env has {layout}, the model was built for {self.agent_layout}"
            )
        self.agent_layout = layout

    def _setup_model(self) -> None:
        if self.env is not None:
            self._check_layout(self.env)
        if self.agent_layout is None:
            raise ValueError("MADDPG needs an env (or a saved model) to know the agents' layout")
        if self.n_steps != 1:
            raise ValueError("MADDPG does not support n-step returns (n_steps must be 1)")
        layout = self.agent_layout
        self._adopt_saved_runs()
        self.pack.envs_per_run(self.n_envs)  # (a clear error when the envs cannot be split between the runs)
        self._convert_train_freq()  # (SB3's, idempotent: checked here, before the replay buffer is allocated)
        assert isinstance(self.train_freq, TrainFreq)
        if self.n_runs > 1 and self.train_freq.unit != TrainFrequencyUnit.STEP:
            raise ValueError("train_freq: a pack counts it in steps ((N, 'step')); SB3 counts episodes over all envs")
        buffer_extra: dict[str, Any] = {"n_agents": layout.n_agents, "n_runs": self.n_runs}
        self.pack.setup(layout)
        if self.pack.explores:
            buffer_extra["exploration"] = self.pack.explorations  # (the pack's own list: the buffer holds no copy)
            if self.replay_buffer_class is None:
                self.replay_buffer_class = MACBReplayBuffer
            elif not issubclass(self.replay_buffer_class, MACBReplayBuffer):
                raise TypeError(
                    f"exploration=MACB needs a replay buffer deriving from MACBReplayBuffer, not {self.replay_buffer_class}"
                )
        elif self.replay_buffer_class is None:
            self.replay_buffer_class = MultiAgentReplayBuffer
        # The layout-derived arguments are passed while building, not stored in the user's kwargs
        user_policy_kwargs, user_buffer_kwargs = self.policy_kwargs, self.replay_buffer_kwargs
        groups = self._share_groups(layout)
        self.policy_kwargs = {
            **user_policy_kwargs,
            "agent_layout": layout,
            "centralized_critic": self.centralized_critic,
            "n_runs": self.n_runs,
            "run_seeds": self.run_seeds,
            "share_actors": groups,
            "share_critics": groups if self.__dict__.get("share_critics") else None,
            "intrinsic_critic": self.__dict__.get("intrinsic_critic", False),
        }
        self.replay_buffer_kwargs = {**user_buffer_kwargs, **buffer_extra}
        try:
            super()._setup_model()
        finally:
            self.policy_kwargs, self.replay_buffer_kwargs = user_policy_kwargs, user_buffer_kwargs

        # Agent i's slice of the joint action, to put its actor's action into its own critic's input
        masks = _block_mask(layout.action_slices, layout.action_dim)[:, None, :]
        self._action_masks: th.Tensor = th.as_tensor(masks, device=self.device)
        self._actor_params: list[th.Tensor] = list(self.actor.parameters())
        self._actor_target_params: list[th.Tensor] = list(self.actor_target.parameters())
        self._critic_params: list[th.Tensor] = list(self.critic.parameters())
        self._critic_target_params: list[th.Tensor] = list(self.critic_target.parameters())
        if self.policy.critic_int is not None:  # (the intrinsic critics' targets follow theirs in the same lerp)
            self._critic_params += list(self.policy.critic_int.parameters())
            self._critic_target_params += list(self.policy.critic_int_target.parameters())
        # the joint action's entries of discrete agents (None: every agent is continuous), read at every step
        self._discrete_mask: np.ndarray | None = layout.discrete_action_mask if self.actor.has_discrete else None
        # preactivation_reg's weight of each joint-action component: 1 / its agent's action_dim for continuous
        # components (a per-agent mean), 0 for discrete ones (their logits have their own penalty)
        dims = np.asarray(layout.action_dims)
        weights = th.as_tensor(np.repeat(1.0 / dims, dims), dtype=th.float32, device=self.device)
        if self.actor.has_discrete:
            weights = weights.masked_fill(self.actor.discrete_mask, 0.0)
        self._preactivation_weights: th.Tensor = weights

    def _adopt_saved_runs(self) -> None:
        """Build :attr:`pack` from the attributes a model saved by sb3_macb <= 0.12 holds instead of one."""
        saved = self.__dict__
        if not {"n_runs", "run_seeds", "explorations", "exploration", "_run_rngs"} & set(saved):
            return
        explorations = saved.pop("explorations", None)
        if "exploration" in saved:  # sb3_macb 0.1 held one MACB as "exploration"
            explorations = [saved.pop("exploration")]
        n_runs = saved.pop("n_runs", 1)
        self.pack = Pack(n_runs, saved.pop("run_seeds", None), explorations)
        self.pack.rngs = saved.pop("_run_rngs", None)

    def _share_groups(self, layout: AgentLayout) -> list[list[int]] | None:
        """
        The sharing groups (agent indices) of ``share_parameters``: ``"all"``, ``"prefix"`` (agents whose names agree
        up to the last ``_``, e.g. mpe2's ``adversary_0``, ``adversary_1``), or lists of agent names (agents not
        named keep their own networks). None: no sharing.
        """
        spec = self.__dict__.get("share_parameters")  # (models saved before sharing existed have none)
        if spec is None:
            return None
        names = list(layout.agents)
        if spec == "all":
            groups = [list(range(len(names)))]
        elif spec == "prefix":
            prefixes: dict[str, list[int]] = {}
            for i, name in enumerate(names):
                prefixes.setdefault(name.rsplit("_", 1)[0], []).append(i)
            groups = list(prefixes.values())
        else:
            unknown = sorted({n for g in spec for n in g} - set(names))
            if unknown:
                raise ValueError(f"share_parameters names agents {unknown} that the env does not have; it has {names}")
            listed = [names.index(n) for g in spec for n in g]
            if len(listed) != len(set(listed)):
                raise ValueError(f"share_parameters lists an agent twice: {spec}")
            groups = [[names.index(n) for n in g] for g in spec if g]
            groups += [[i] for i in range(len(names)) if i not in listed]
        groups = sorted(groups, key=min)
        from sb3_macb.maddpg.policies import check_share_groups

        check_share_groups(layout, groups)
        return groups

    def set_env(self, env: GymEnv | Any, force_reset: bool = True) -> None:
        env = self._wrap_env(env, self.verbose)
        self._check_layout(env)  # before SB3 adopts the env, so a mismatched one is refused, not half-set
        super().set_env(env, force_reset=force_reset)

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        buffer = self.replay_buffer
        if not isinstance(buffer, MultiAgentReplayBuffer):
            raise TypeError(f"Expected a MultiAgentReplayBuffer, the file holds a {type(buffer).__name__}")
        if getattr(buffer, "n_runs", 1) != self.n_runs or buffer.n_envs != self.n_envs:
            raise ValueError("This replay buffer was saved by a model with another number of runs or envs than this model's")
        if any(e is not None for e in self.explorations) and not isinstance(buffer, MACBReplayBuffer):
            raise ValueError("This model uses MACB but the replay buffer has no hash keys (it was saved without MACB)")
        if isinstance(buffer, MACBReplayBuffer):
            n_tables = max((e.n_tables for e in self.explorations if e is not None), default=-1)
            if buffer.hash_keys.shape[-1] != n_tables:
                raise ValueError("This replay buffer was saved by a model using MACB with other settings than this model's")
            buffer.explorations = self.pack.explorations

    def dump_logs(self) -> None:
        explorations = [e for e in self.explorations if e is not None]
        if explorations:  # (means over the runs of a pack)
            self.logger.record("exploration/num_codes", float(np.mean([e.num_codes for e in explorations])))
            self.logger.record("exploration/count1_percent", 100.0 * float(np.mean([e.count1_fraction for e in explorations])))
            mean_bonus = self.replay_buffer.pop_mean_bonus() if isinstance(self.replay_buffer, MACBReplayBuffer) else None
            if mean_bonus is not None:
                self.logger.record("exploration/mean_bonus", mean_bonus)
            rates = [r for r in (getattr(e, "sketch_collision_rate", None) for e in explorations) if r is not None]
            if rates:
                self.logger.record("exploration/sketch_collision_rate", max(rates))
                if max(rates) > SKETCH_SATURATED:
                    warnings.warn(
                        f"MACB's count-min sketch is saturated: more than {SKETCH_SATURATED:.0%} of the codes never seen are "
                        "counted as seen, so counts are overestimated and bonuses too small; use a sketch_width well above "
                        "the number of distinct codes, or table='exact' (exploration/sketch_collision_rate is logged)",
                        stacklevel=2,
                    )
        super().dump_logs()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self.gradient_steps < 0:  # SB3 passes the steps of all envs; each run of a pack does its own run's count
            gradient_steps = self.pack.run_steps(gradient_steps)
        self.policy.set_training_mode(True)
        critic_int = self.policy.critic_int
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        self._update_learning_rate(optimizers if critic_int is None else [*optimizers, critic_int.optimizer])
        for exploration in self.explorations:  # a scheduled beta follows training as the learning rate does
            if exploration is not None:
                exploration.progress_remaining = self._current_progress_remaining
        rngs = self.pack.rngs
        assert rngs is not None
        actor_losses, critic_losses, int_losses = [], [], []
        for _ in range(gradient_steps):
            self._n_updates += 1
            # one minibatch per run, each from its own envs with its own generator: (n_runs, batch, ...)
            data = self.replay_buffer.sample_runs(
                batch_size, rngs, env=self._vec_normalize_env, separate_bonus=critic_int is not None
            )
            target_q, target_int = self._td_targets(data)
            critic_losses.append(self._regress(self.critic, data, target_q))
            if critic_int is not None:
                int_losses.append(self._regress(critic_int, data, target_int))  # type: ignore[arg-type]
            if self._n_updates % self.policy_delay == 0:
                actor_losses.append(self._actor_step(data, batch_size))
                self._update_targets()

        groups = self.agent_layout.n_agents * self.n_runs  # type: ignore[union-attr]
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if actor_losses:
            self.logger.record("train/actor_loss", th.stack(actor_losses).mean().item() / groups)
        self.logger.record("train/critic_loss", th.stack(critic_losses).mean().item() / groups)
        if int_losses:
            self.logger.record("train/intrinsic_critic_loss", th.stack(int_losses).mean().item() / groups)

    def _td_targets(self, data: RunSamples) -> tuple[th.Tensor, th.Tensor | None]:
        """
        Each critic's target ``r_i + gamma * (1 - done) * Q'_i(s', mu'(s'))`` (the minimum over twin critics), of shape
        (n_runs, n_agents, batch), and with an intrinsic critic its target ``bonus + intrinsic_gamma * Q'_int(s',
        mu'(s'))`` (never cut at an episode's end), else None. With ``target_policy_noise``, the target actors'
        continuous actions are smoothed by clipped Gaussian noise drawn from each run's own generator (a packed run
        draws what its solo run draws); discrete target actions stay one-hot.
        """
        critic_int_target = self.policy.critic_int_target
        with th.no_grad():
            next_actions = self.actor_target(data.next_observations)
            if self.target_policy_noise > 0:
                noise = self.pack.draws("standard_normal", next_actions.shape[1:], self.device).mul_(self.target_policy_noise)
                if self.actor.has_discrete:
                    noise = noise.masked_fill(self.actor.discrete_mask, 0.0)
                next_actions = (next_actions + noise.clamp_(-self.target_noise_clip, self.target_noise_clip)).clamp_(-1, 1)
            next_q = self.critic_target(data.next_observations, next_actions)  # (n_critics, n_runs, n_agents, batch)
            next_q = next_q.min(dim=0).values if next_q.shape[0] > 1 else next_q[0]
            rewards = data.rewards.transpose(1, 2)  # (n_runs, n_agents, batch): each critic learns its own reward
            not_done = 1.0 - data.dones.unsqueeze(1)  # (n_runs, 1, batch)
            target_q = rewards + self.gamma * not_done * next_q
            if critic_int_target is None:
                return target_q, None
            next_int = critic_int_target(data.next_observations, next_actions)
            next_int = next_int.min(dim=0).values if next_int.shape[0] > 1 else next_int[0]
            return target_q, data.bonus.transpose(1, 2) + self.intrinsic_gamma * next_int  # type: ignore[union-attr]

    @staticmethod
    def _regress(critic: MultiAgentCritic, data: RunSamples, target: th.Tensor) -> th.Tensor:
        """
        One gradient step of ``critic`` towards ``target`` on the minibatch's observations and actions: the sum over
        runs, agents and twin critics of each critic's mean squared error (so the groups' gradients stay separate).
        :return: The loss, detached.
        """
        loss = (critic(data.observations, data.actions) - target).pow(2).mean(dim=-1).sum()
        critic.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        critic.optimizer.step()
        return loss.detach()

    def _actor_step(self, data: RunSamples, batch_size: int) -> th.Tensor:
        """
        One gradient step of the actors: agent ``i`` maximizes its first critic's ``Q_i(s, a)`` where ``a`` is the
        minibatch's joint action with agent ``i``'s slice replaced by its actor's action (critic weights frozen; with
        an intrinsic critic, ``Q_i + intrinsic_coef * Q_int,i``). Discrete agents act by a Gumbel-max sample with the
        straight-through Gumbel-softmax gradient (noise from each run's own generator) and their logits are kept
        small by ``DISCRETE_LOGIT_PENALTY`` times their mean square, as in the MADDPG paper; ``preactivation_reg``
        penalizes continuous agents' pre-``tanh`` outputs.
        :return: The loss, detached.
        """
        gumbel = None
        if self.actor.has_discrete:
            gumbel = self.pack.draws("gumbel", (batch_size, self.agent_layout.action_dim), self.device)  # type: ignore[union-attr]
        raw = self.actor.raw(data.observations)  # (n_runs, batch, action_dim), logits for discrete agents
        pi = self.actor.squash(raw, gumbel, straight_through=gumbel is not None).unsqueeze(1)
        actions = data.actions.unsqueeze(1)
        mixed = actions + self._action_masks * (pi - actions)  # (n_runs, n_agents, batch, action_dim)
        q = self.critic.q1_forward(data.observations, mixed, detach_params=True)
        critic_int = self.policy.critic_int
        if critic_int is not None:
            q = q + self.intrinsic_coef * critic_int.q1_forward(data.observations, mixed, detach_params=True)
        loss = -q.mean(dim=-1).sum()
        if self.actor.has_discrete:
            loss = loss + DISCRETE_LOGIT_PENALTY * raw[..., self.actor.discrete_mask].pow(2).mean(dim=(-2, -1)).sum()
        if self.preactivation_reg > 0:
            loss = loss + self._preactivation_penalty(raw)
        self.actor.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.actor.optimizer.step()
        return loss.detach()

    def _update_targets(self) -> None:
        """Polyak averaging of every target network (critics, intrinsic critics, actors) towards its network by ``tau``."""
        with th.no_grad():
            lerp_(self._critic_target_params, self._critic_params, self.tau)
            lerp_(self._actor_target_params, self._actor_params, self.tau)

    def _preactivation_penalty(self, raw: th.Tensor) -> th.Tensor:
        """
        ``preactivation_reg`` times, summed over runs and agents, each continuous agent's mean squared pre-``tanh``
        output (the mean over the minibatch and the agent's own action components, as the MADDPG code's per-agent
        loss). Discrete components are left out (weight 0).

        :param raw: (n_runs, batch, action_dim) outputs before squashing.
        """
        return self.preactivation_reg * (raw.pow(2).mean(dim=-2) * self._preactivation_weights).sum()

    def learn(
        self: SelfMADDPG,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "MADDPG",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfMADDPG:
        switch = self.flush_denormal and not flushing_denormals()  # (a user's own setting is left alone)
        if switch:
            th.set_flush_denormal(True)
        try:
            return super().learn(
                total_timesteps=total_timesteps,
                callback=callback,
                log_interval=log_interval,
                tb_log_name=tb_log_name,
                reset_num_timesteps=reset_num_timesteps,
                progress_bar=progress_bar,
            )
        finally:
            if switch:
                th.set_flush_denormal(False)

    # --- saving -------------------------------------------------------------------------------------------------

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """
        SB3's ``save``, written atomically: the zip goes to a temporary file that replaces ``path`` only once it is
        complete, so a process killed while saving leaves the previous file intact.
        """
        if isinstance(path, (str, os.PathLike)):
            with atomic_write(with_suffix(path, ".zip")) as file:
                super().save(file, exclude=exclude, include=include)  # type: ignore[arg-type]
        else:
            super().save(path, exclude=exclude, include=include)

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """SB3's ``save_replay_buffer``, written atomically (see :meth:`save`)."""
        if isinstance(path, (str, os.PathLike)):
            with atomic_write(with_suffix(path, ".pkl")) as file:
                super().save_replay_buffer(file)  # type: ignore[arg-type]
        else:
            super().save_replay_buffer(path)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        if self.__dict__.get("intrinsic_critic"):
            state_dicts = [*state_dicts, "policy.critic_int.optimizer"]
        if self.n_runs == 1 and self.explorations[0] is not None:
            state_dicts = [*state_dicts, "exploration"]
        elif any(e is not None for e in self.explorations):
            state_dicts = [*state_dicts, "_exploration_pack"]
        return state_dicts, variables

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "_action_masks",
            "_discrete_mask",
            "_preactivation_weights",
            "_actor_params",
            "_actor_target_params",
            "_critic_params",
            "_critic_target_params",
        ]

    # --- acting in a raw PettingZoo loop ----------------------------------------------------------------------------

    def predict_agents(self, observations: dict[str, Any], deterministic: bool = True) -> dict[str, Any]:
        """
        Every agent's action for one step of a PettingZoo ``ParallelEnv``, from its dict of observations (the
        agents' own observations, as ``env.step`` and ``env.reset`` return them): continuous actions as arrays of the
        agent's size, discrete ones as action indices, ready for ``env.step``::

            observations, _ = env.reset(seed=0)
            while env.agents:
                observations, rewards, terminations, truncations, infos = env.step(model.predict_agents(observations))

        :param observations: One observation per agent, keyed by the agent names the model was trained with.
        :param deterministic: The actors' actions without exploration noise.
        """
        if self.n_runs != 1:
            raise ValueError(f"A pack of {self.n_runs} runs acts run by run: use model.get_run(k).predict_agents(...)")
        layout = self.agent_layout
        assert layout is not None
        missing = [agent for agent in layout.agents if agent not in observations]
        if missing:
            raise KeyError(f"No observation for agent(s) {missing}; the model's agents are {list(layout.agents)}")
        joint = np.concatenate([np.asarray(observations[agent], dtype=np.float32).ravel() for agent in layout.agents])
        action, _ = self.predict(joint, deterministic=deterministic)
        return {
            agent: int(np.argmax(action[sl])) if discrete else np.asarray(action[sl], dtype=np.float32)
            for agent, sl, discrete in zip(layout.agents, layout.action_slices, layout.discrete_agents)
        }

    # --- a pack's run as an ordinary model -------------------------------------------------------------------------

    def get_run(self, k: int, env: GymEnv | Any = None) -> "MADDPG":
        """
        Run ``k`` of a pack as an ordinary MADDPG model (``n_runs=1``): its networks, target networks, optimizer
        state, MACB count table, random generator, step and update counts. The replay buffer is not copied.

        :param k: The run, 0 to ``n_runs - 1``.
        :param env: The env to attach (optional, as for :meth:`load`).
        """
        run = self.pack.run(k, self.agent_layout)  # (an IndexError for a run out of range)
        defaults = inspect.signature(MADDPG.__init__).parameters  # (for settings a model saved by an older version lacks)
        settings = {name: copy.deepcopy(getattr(self, name, defaults[name].default)) for name in self._RUN_SETTINGS}
        solo = type(self)(
            policy=self.policy_class,  # type: ignore[arg-type]  # (a MADDPGPolicy class)
            env=None,
            device=self.device,
            seed=None if run.seeds is None else run.seeds[0],
            n_runs=1,
            run_seeds=run.seeds,
            exploration=run.explorations[0],
            action_noise=None if self.action_noise is None else self.pack.run_noise(self.action_noise, k, self.n_envs),
            learning_starts=self.pack.run_steps(self.learning_starts),
            # the package's own buffers are chosen again from the run's exploration; a user's class is kept
            replay_buffer_class=None
            if self.replay_buffer_class in (MACBReplayBuffer, MultiAgentReplayBuffer)
            else self.replay_buffer_class,
            stats_window_size=self._stats_window_size,
            _init_setup_model=False,
            **settings,
        )
        solo.pack = run  # (its generator's state too)
        solo.observation_space, solo.action_space = self.observation_space, self.action_space
        solo.n_envs, solo.agent_layout = self.envs_per_run, self.agent_layout
        solo._setup_model()
        solo.num_timesteps = self.pack.run_steps(self.num_timesteps)
        solo._total_timesteps = self.pack.run_steps(self._total_timesteps)
        solo._num_timesteps_at_start = self.pack.run_steps(self._num_timesteps_at_start)
        solo._episode_num = self.pack.run_steps(self._episode_num)
        solo._n_updates = self._n_updates
        solo._current_progress_remaining = self._current_progress_remaining
        modules = [("actor", "actor"), ("actor_target", "actor"), ("critic", "critic"), ("critic_target", "critic")]
        if self.policy.critic_int is not None:
            modules += [("critic_int", "critic"), ("critic_int_target", "critic")]
        with th.no_grad():
            for name, module in modules:
                mine, theirs = getattr(self.policy, name).state_dict(), getattr(solo.policy, name).state_dict()
                getattr(solo.policy, name).load_state_dict({key: self._run_slice(mine[key], module, k) for key in theirs})
        for name in [m for m, _ in modules if not m.endswith("_target")]:
            opt, solo_opt = getattr(self.policy, name).optimizer, getattr(solo.policy, name).optimizer
            state = opt.state_dict()
            state["state"] = {
                idx: {key: (self._run_slice(v, name, k) if v.dim() > 0 else v.clone()) for key, v in entry.items()}
                for idx, entry in state["state"].items()
            }
            solo_opt.load_state_dict(state)
        if env is not None:
            solo.set_env(env)
        return solo

    def _run_slice(self, tensor: th.Tensor, module: str, k: int) -> th.Tensor:
        """
        Run ``k``'s groups of a stacked actor (groups: run, network) or critic (groups: critic, run, network) tensor;
        a run has one network per agent, or one per sharing group.
        """
        if module == "actor":
            return tensor.reshape(self.n_runs, -1, *tensor.shape[1:])[k].clone()
        n_critics = self.policy.n_critics
        return tensor.reshape(n_critics, self.n_runs, -1, *tensor.shape[1:])[:, k].reshape(-1, *tensor.shape[1:]).clone()
