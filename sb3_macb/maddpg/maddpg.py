from typing import Any, ClassVar, TypeVar

import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.td3 import TD3

from sb3_macb.buffers import MACBReplayBuffer, MultiAgentReplayBuffer
from sb3_macb.envs.joint_env import AgentLayout, is_pettingzoo_env, make_joint_env
from sb3_macb.exploration.macb import MACB
from sb3_macb.maddpg.policies import MADDPGPolicy, MlpPolicy, MultiAgentActor, MultiAgentCritic, _block_mask

SelfMADDPG = TypeVar("SelfMADDPG", bound="MADDPG")


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

    :param policy: The policy model to use (``"MlpPolicy"``).
    :param env: The environment to learn from: a joint env, a PettingZoo env, or a registered env id.
    :param learning_rate: Learning rate for Adam (actors and critics); can be a schedule.
    :param buffer_size: Size of the replay buffer.
    :param learning_starts: How many steps to collect transitions for before learning starts.
    :param batch_size: Minibatch size for each gradient update (one minibatch, the same indices, for all agents).
    :param tau: The soft update coefficient ("Polyak update", between 0 and 1).
    :param gamma: The discount factor.
    :param train_freq: Update the model every ``train_freq`` steps, or a tuple like ``(5, "step")``.
    :param gradient_steps: How many gradient steps to do after each rollout (-1: as many as env steps).
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
    :param stats_window_size: Window size for the rollout logging.
    :param tensorboard_log: The log location for tensorboard (if None, no logging).
    :param policy_kwargs: Additional arguments for the policy (``net_arch``, ``n_critics``, ...).
    :param verbose: Verbosity level: 0 none, 1 info, 2 debug.
    :param seed: Seed for the pseudo random generators.
    :param device: Device (cpu, cuda, ...) on which the code should be run.
    :param _init_setup_model: Whether or not to build the network at the creation of the instance.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: MADDPGPolicy
    actor: MultiAgentActor
    actor_target: MultiAgentActor
    critic: MultiAgentCritic
    critic_target: MultiAgentCritic
    replay_buffer: MultiAgentReplayBuffer

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
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        policy_delay: int = 1,
        target_policy_noise: float = 0.0,
        target_noise_clip: float = 0.5,
        centralized_critic: bool = True,
        exploration: MACB | dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ):
        if policy_kwargs and ("agent_layout" in policy_kwargs or "centralized_critic" in policy_kwargs):
            raise ValueError(
                "Pass centralized_critic to MADDPG itself, not in policy_kwargs; the agent layout is read from the env"
            )
        if replay_buffer_class is not None and not issubclass(replay_buffer_class, MultiAgentReplayBuffer):
            raise TypeError(
                f"replay_buffer_class must derive from sb3_macb.buffers.MultiAgentReplayBuffer, got {replay_buffer_class}"
            )
        self.agent_layout: AgentLayout | None = None
        self.centralized_critic = centralized_critic
        self.exploration = MACB.from_config(exploration)
        # MACB's settings travel in the saved data; its matrices and count tables are saved like a state dict
        self.exploration_config: dict[str, Any] | None = None
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
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
        if _init_setup_model:
            self._setup_model()

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
        if self.exploration is None and self.exploration_config is not None:
            self.exploration = MACB(**self.exploration_config)  # loading a saved model
        buffer_extra: dict[str, Any] = {"n_agents": layout.n_agents}
        if self.exploration is not None:
            self.exploration.setup(layout, seed=self.seed)
            self.exploration_config = self.exploration.config
            buffer_extra["exploration"] = self.exploration
            if self.replay_buffer_class is None:
                self.replay_buffer_class = MACBReplayBuffer
            elif not issubclass(self.replay_buffer_class, MACBReplayBuffer):
                raise TypeError(f"exploration=MACB needs a replay buffer deriving from MACBReplayBuffer, not {self.replay_buffer_class}")
        elif self.replay_buffer_class is None:
            self.replay_buffer_class = MultiAgentReplayBuffer
        # The layout-derived arguments are passed while building, not stored in the user's kwargs
        user_policy_kwargs, user_buffer_kwargs = self.policy_kwargs, self.replay_buffer_kwargs
        self.policy_kwargs = {**user_policy_kwargs, "agent_layout": layout, "centralized_critic": self.centralized_critic}
        self.replay_buffer_kwargs = {**user_buffer_kwargs, **buffer_extra}
        try:
            super()._setup_model()
        finally:
            self.policy_kwargs, self.replay_buffer_kwargs = user_policy_kwargs, user_buffer_kwargs

        # Agent i's slice of the joint action, to put its actor's action into its own critic's input
        masks = _block_mask(layout.action_slices, layout.action_dim)[:, None, :]
        self._action_masks = th.as_tensor(masks, device=self.device)
        self._actor_params = list(self.actor.parameters())
        self._actor_target_params = list(self.actor_target.parameters())
        self._critic_params = list(self.critic.parameters())
        self._critic_target_params = list(self.critic_target.parameters())

    def set_env(self, env: GymEnv | Any, force_reset: bool = True) -> None:
        env = self._wrap_env(env, self.verbose)
        self._check_layout(env)  # before SB3 adopts the env, so a mismatched one is refused, not half-set
        super().set_env(env, force_reset=force_reset)

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        buffer = self.replay_buffer
        if not isinstance(buffer, MultiAgentReplayBuffer):
            raise TypeError(f"Expected a MultiAgentReplayBuffer, the file holds a {type(buffer).__name__}")
        if self.exploration is not None and not isinstance(buffer, MACBReplayBuffer):
            raise ValueError("This model uses MACB but the replay buffer has no hash keys (it was saved without MACB)")
        if isinstance(buffer, MACBReplayBuffer):
            if self.exploration is None or buffer.hash_keys.shape[-1] != self.exploration.n_tables:
                raise ValueError("This replay buffer was saved by a model using MACB with other settings than this model's")
            buffer.exploration = self.exploration

    def dump_logs(self) -> None:
        if self.exploration is not None:
            self.logger.record("exploration/num_codes", self.exploration.num_codes)
            self.logger.record("exploration/count1_percent", 100.0 * self.exploration.count1_fraction)
            mean_bonus = self.replay_buffer.pop_mean_bonus() if isinstance(self.replay_buffer, MACBReplayBuffer) else None
            if mean_bonus is not None:
                self.logger.record("exploration/mean_bonus", mean_bonus)
        super().dump_logs()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        actor_losses, critic_losses = [], []
        for _ in range(gradient_steps):
            self._n_updates += 1
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            rewards = data.rewards.T  # (n_agents, batch): each critic learns from its own agent's reward
            not_done = 1.0 - data.dones.T  # (1, batch)

            with th.no_grad():
                next_actions = self.actor_target(data.next_observations)
                if self.target_policy_noise > 0:
                    noise = th.randn_like(next_actions).mul_(self.target_policy_noise)
                    next_actions = (next_actions + noise.clamp_(-self.target_noise_clip, self.target_noise_clip)).clamp_(-1, 1)
                next_q = self.critic_target(data.next_observations, next_actions)  # (n_critics, n_agents, batch)
                next_q = next_q.min(dim=0).values if next_q.shape[0] > 1 else next_q[0]
                target_q = rewards + self.gamma * not_done * next_q

            current_q = self.critic(data.observations, data.actions)
            # Sum over agents (and critics) of each critic's MSE: the agents' gradients stay separate
            critic_loss = (current_q - target_q).pow(2).mean(dim=-1).sum()
            self.critic.optimizer.zero_grad(set_to_none=True)
            critic_loss.backward()
            self.critic.optimizer.step()
            critic_losses.append(critic_loss.detach())

            if self._n_updates % self.policy_delay == 0:
                # Agent i's critic sees the buffer actions with agent i's slice replaced by its actor's action
                pi = self.actor(data.observations)
                mixed = data.actions + self._action_masks * (pi - data.actions)
                q = self.critic.q1_forward(data.observations, mixed, detach_params=True)
                actor_loss = -q.mean(dim=-1).sum()
                self.actor.optimizer.zero_grad(set_to_none=True)
                actor_loss.backward()
                self.actor.optimizer.step()
                actor_losses.append(actor_loss.detach())

                with th.no_grad():
                    th._foreach_lerp_(self._critic_target_params, self._critic_params, self.tau)
                    th._foreach_lerp_(self._actor_target_params, self._actor_params, self.tau)

        n_agents = self.agent_layout.n_agents  # type: ignore[union-attr]
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if actor_losses:
            self.logger.record("train/actor_loss", th.stack(actor_losses).mean().item() / n_agents)
        self.logger.record("train/critic_loss", th.stack(critic_losses).mean().item() / n_agents)

    def learn(
        self: SelfMADDPG,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "MADDPG",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfMADDPG:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        if self.exploration is not None:
            state_dicts = [*state_dicts, "exploration"]
        return state_dicts, variables

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "_action_masks",
            "_actor_params",
            "_actor_target_params",
            "_critic_params",
            "_critic_target_params",
        ]
