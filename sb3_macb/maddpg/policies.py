"""Per-agent actors and critics of MADDPG, held as stacked tensors so that all agents run in one batched pass."""

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_macb.common.grouped_mlp import GroupedMLP
from sb3_macb.envs.joint_env import AgentLayout


def _block_mask(rows: list[slice], width: int) -> np.ndarray:
    mask = np.zeros((len(rows), width), dtype=np.float32)
    for i, sl in enumerate(rows):
        mask[i, sl] = 1.0
    return mask


class MultiAgentActor(nn.Module):
    """
    One deterministic actor per agent, each reading its own observation; the output is the joint action in
    [-1, 1] (tanh), each agent writing its own slice.

    :param layout: The agents' observation and action sizes.
    :param net_arch: Hidden layer sizes of each actor.
    :param activation_fn: Activation function.
    """

    def __init__(self, layout: AgentLayout, net_arch: list[int], activation_fn: type[nn.Module] = nn.ReLU):
        super().__init__()
        self.mu = GroupedMLP(
            _block_mask(layout.obs_slices, layout.obs_dim),
            net_arch,
            _block_mask(layout.action_slices, layout.action_dim),
            activation_fn,
            sum_groups=True,
        )

    def forward(self, obs: th.Tensor) -> th.Tensor:
        return th.tanh(self.mu(obs))


class MultiAgentCritic(nn.Module):
    """
    ``n_critics`` Q-networks per agent, all evaluated in one batched pass. Group ``c * n_agents + i`` is critic
    ``c`` of agent ``i``. A centralized critic reads every agent's observation and action; an independent one
    (``centralized=False``) reads only its own agent's observation and action.

    :param layout: The agents' observation and action sizes.
    :param net_arch: Hidden layer sizes of each critic.
    :param activation_fn: Activation function.
    :param n_critics: Number of critics per agent (2 for MATD3).
    :param centralized: Whether each critic sees all agents (MADDPG) or only its own agent (independent DDPG).
    """

    def __init__(
        self,
        layout: AgentLayout,
        net_arch: list[int],
        activation_fn: type[nn.Module] = nn.ReLU,
        n_critics: int = 1,
        centralized: bool = True,
    ):
        super().__init__()
        self.n_agents = layout.n_agents
        self.n_critics = n_critics
        n_in = layout.obs_dim + layout.action_dim
        if centralized:
            in_mask = np.ones((layout.n_agents, n_in), dtype=np.float32)
        else:
            obs_mask = _block_mask(layout.obs_slices, layout.obs_dim)
            act_mask = _block_mask(layout.action_slices, layout.action_dim)
            in_mask = np.concatenate([obs_mask, act_mask], axis=1)
        in_mask = np.tile(in_mask, (n_critics, 1))
        self.q_net = GroupedMLP(in_mask, net_arch, np.ones((len(in_mask), 1), dtype=np.float32), activation_fn)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        :return: Q-values of shape (n_critics, n_agents, batch).
        """
        q = self.q_net(th.cat([obs, actions], dim=-1))
        return q.view(self.n_critics, self.n_agents, -1)

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor, detach_params: bool = False) -> th.Tensor:
        """
        First critic of each agent, where agent ``i``'s critic gets the ``i``-th row of ``actions``.

        :param obs: (batch, obs_dim) joint observations.
        :param actions: (n_agents, batch, action_dim) joint actions, one per agent.
        :param detach_params: Do not record gradients for the critic's parameters.
        :return: (n_agents, batch)
        """
        x = th.cat([obs.expand(self.n_agents, *obs.shape), actions], dim=-1)
        return self.q_net(x, groups=slice(0, self.n_agents), detach_params=detach_params).squeeze(-1)


class MADDPGPolicy(BasePolicy):
    """
    Policy of MADDPG: decentralized actors and centralized critics for every agent, with their targets.

    :param observation_space: Joint observation space.
    :param action_space: Joint action space.
    :param lr_schedule: Learning rate schedule (could be constant).
    :param agent_layout: How the joint vectors split between agents (set by MADDPG from the env).
    :param net_arch: Hidden sizes of actors and critics: a list for both, or a dict with ``pi`` and ``qf``.
    :param activation_fn: Activation function.
    :param n_critics: Number of critics per agent (1 for MADDPG, 2 for MATD3).
    :param centralized_critic: Whether each agent's critic sees all agents' observations and actions.
    :param optimizer_class: The optimizer to use, ``th.optim.Adam`` by default.
    :param optimizer_kwargs: Additional keyword arguments for the optimizer. By default a fused Adam
        implementation is used where the device supports it.
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        agent_layout: AgentLayout | None = None,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        n_critics: int = 1,
        centralized_critic: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
    ):
        super().__init__(
            observation_space,
            action_space,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            squash_output=True,
            normalize_images=False,
        )
        if agent_layout is None:
            raise ValueError("MADDPGPolicy needs the agent layout of a joint env (see sb3_macb.make_joint_env)")
        if n_critics < 1:
            raise ValueError(f"n_critics must be >= 1, got {n_critics}")
        if net_arch is None:
            net_arch = [400, 300]
        if isinstance(net_arch, dict):
            unknown = set(net_arch) - {"pi", "qf"}
            if unknown or not {"pi", "qf"} <= set(net_arch):
                raise ValueError(f"net_arch as a dict needs exactly the keys 'pi' and 'qf', got {sorted(net_arch)}")
            actor_arch, critic_arch = list(net_arch["pi"]), list(net_arch["qf"])
        else:
            actor_arch, critic_arch = list(net_arch), list(net_arch)
        self.agent_layout = agent_layout
        self.net_arch = net_arch
        self.activation_fn = activation_fn
        self.n_critics = n_critics
        self.centralized_critic = centralized_critic
        self._actor_kwargs = dict(layout=agent_layout, net_arch=actor_arch, activation_fn=activation_fn)
        self._critic_kwargs = dict(
            layout=agent_layout,
            net_arch=critic_arch,
            activation_fn=activation_fn,
            n_critics=n_critics,
            centralized=centralized_critic,
        )
        self._build(lr_schedule)

    def _build(self, lr_schedule: Schedule) -> None:
        self.actor = MultiAgentActor(**self._actor_kwargs)
        self.actor_target = MultiAgentActor(**self._actor_kwargs)
        self.actor_target.load_state_dict(self.actor.state_dict())
        self.critic = MultiAgentCritic(**self._critic_kwargs)
        self.critic_target = MultiAgentCritic(**self._critic_kwargs)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.actor_target.requires_grad_(False)
        self.critic_target.requires_grad_(False)
        self.actor.optimizer = self._make_optimizer(self.actor.parameters(), lr_schedule)
        self.critic.optimizer = self._make_optimizer(self.critic.parameters(), lr_schedule)
        self.set_training_mode(False)

    def _make_optimizer(self, params: Any, lr_schedule: Schedule) -> th.optim.Optimizer:
        kwargs = dict(self.optimizer_kwargs)
        if self.optimizer_class is th.optim.Adam and not ({"fused", "foreach"} & set(kwargs)):
            kwargs["fused"] = True  # one kernel for all stacked tensors; supported on CPU and CUDA
        return self.optimizer_class(params, lr=lr_schedule(1), **kwargs)  # type: ignore[call-arg]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            dict(
                agent_layout=self.agent_layout,
                net_arch=self.net_arch,
                activation_fn=self.activation_fn,
                n_critics=self.n_critics,
                centralized_critic=self.centralized_critic,
                optimizer_class=self.optimizer_class,
                optimizer_kwargs=self.optimizer_kwargs,
                lr_schedule=self._dummy_schedule,
            )
        )
        return data

    def forward(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return self._predict(observation, deterministic=deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        # MADDPG actors are deterministic: exploration comes from action noise
        return self.actor(observation)  # type: ignore[arg-type]

    def set_training_mode(self, mode: bool) -> None:
        """
        Put the actors and critics in training or evaluation mode.

        SB3 switches modes at every ``predict()`` and ``train()``, i.e. twice per environment step. ``Module.train``
        walks all submodules through ``nn.Module.__setattr__``; setting the flag on the precomputed list of
        submodules does the same in a fraction of the time.
        """
        modules = self.__dict__.get("_mode_modules")
        if modules is None:
            modules = [*self.actor.modules(), *self.critic.modules()]
            self.__dict__["_mode_modules"] = modules
        for module in modules:
            module.__dict__["training"] = mode
        self.__dict__["training"] = mode


MlpPolicy = MADDPGPolicy

