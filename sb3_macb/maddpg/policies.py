"""Per-agent actors and critics of MADDPG, held as stacked tensors so that all agents run in one batched pass."""

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_macb.common.block_adam import BlockAdam
from sb3_macb.common.grouped_mlp import GroupedMLP
from sb3_macb.envs.joint_env import AgentLayout


def _block_mask(rows: list[slice], width: int) -> np.ndarray:
    mask = np.zeros((len(rows), width), dtype=np.float32)
    for i, sl in enumerate(rows):
        mask[i, sl] = 1.0
    return mask


def _generators(run_seeds: list[int] | None) -> list[th.Generator] | None:
    """One torch generator per run, seeded as ``th.manual_seed(seed)`` would seed the global one."""
    return None if run_seeds is None else [th.Generator().manual_seed(int(seed)) for seed in run_seeds]


def _split_runs(x: th.Tensor, n_runs: int) -> th.Tensor:
    """(N, D) rows, run-major (N/n_runs per run), as (n_runs, N/n_runs, D); a (n_runs, n, D) tensor as it is."""
    if x.dim() == 3:
        if x.shape[0] != n_runs:
            raise ValueError(f"Expected {n_runs} runs on the first axis, got shape {tuple(x.shape)}")
        return x
    if x.shape[0] % n_runs:
        raise ValueError(
            f"A pack of {n_runs} runs takes observations run by run, n per run ({n_runs} * n rows); got {x.shape[0]} rows"
        )
    return x.reshape(n_runs, x.shape[0] // n_runs, x.shape[-1])


class MultiAgentActor(nn.Module):
    """
    One deterministic actor per agent (and per run of a pack), each reading its own observation; the output is
    the joint action in [-1, 1] (tanh), each agent writing its own slice. Group ``r * n_agents + i`` is agent
    ``i`` of run ``r``.

    :param layout: The agents' observation and action sizes.
    :param net_arch: Hidden layer sizes of each actor.
    :param activation_fn: Activation function.
    :param n_runs: Independent runs whose actors are stacked together (1: an ordinary model).
    :param generators: One torch generator per run for the initial weights (None: the global one).
    """

    def __init__(
        self,
        layout: AgentLayout,
        net_arch: list[int],
        activation_fn: type[nn.Module] = nn.ReLU,
        n_runs: int = 1,
        generators: list[th.Generator] | None = None,
    ):
        super().__init__()
        self.n_agents = layout.n_agents
        self.n_runs = n_runs
        self.mu = GroupedMLP(
            np.tile(_block_mask(layout.obs_slices, layout.obs_dim), (n_runs, 1)),
            net_arch,
            np.tile(_block_mask(layout.action_slices, layout.action_dim), (n_runs, 1)),
            activation_fn,
            group_runs=np.repeat(np.arange(n_runs), layout.n_agents),
            generators=generators,
        )

    def forward(self, obs: th.Tensor) -> th.Tensor:
        """
        :param obs: (n_runs, batch, obs_dim), or (n_runs * n, obs_dim) with the runs' rows one run after another.
        :return: Joint actions, of the same leading shape as ``obs``.
        """
        x = _split_runs(obs, self.n_runs)
        runs, batch, dim = x.shape
        x = x.unsqueeze(1).expand(runs, self.n_agents, batch, dim).reshape(runs * self.n_agents, batch, dim)
        out = self.mu(x)
        # each agent writes its own slice (the others' outputs are exact zeros): the sum assembles the joint action
        action = th.tanh(out.view(runs, self.n_agents, batch, -1).sum(dim=1))
        return action if obs.dim() == 3 else action.reshape(obs.shape[0], -1)


class MultiAgentCritic(nn.Module):
    """
    ``n_critics`` Q-networks per agent (and per run of a pack), all evaluated in one batched pass. Group
    ``(c * n_runs + r) * n_agents + i`` is critic ``c`` of agent ``i`` in run ``r``. A centralized critic reads every
    agent's observation and action; an independent one (``centralized=False``) reads only its own agent's.

    :param layout: The agents' observation and action sizes.
    :param net_arch: Hidden layer sizes of each critic.
    :param activation_fn: Activation function.
    :param n_critics: Number of critics per agent (2 for MATD3).
    :param centralized: Whether each critic sees all agents (MADDPG) or only its own agent (independent DDPG).
    :param n_runs: Independent runs whose critics are stacked together (1: an ordinary model).
    :param generators: One torch generator per run for the initial weights (None: the global one).
    """

    def __init__(
        self,
        layout: AgentLayout,
        net_arch: list[int],
        activation_fn: type[nn.Module] = nn.ReLU,
        n_critics: int = 1,
        centralized: bool = True,
        n_runs: int = 1,
        generators: list[th.Generator] | None = None,
    ):
        super().__init__()
        self.n_agents = layout.n_agents
        self.n_critics = n_critics
        self.n_runs = n_runs
        n_in = layout.obs_dim + layout.action_dim
        if centralized:
            in_mask = np.ones((layout.n_agents, n_in), dtype=np.float32)
        else:
            obs_mask = _block_mask(layout.obs_slices, layout.obs_dim)
            act_mask = _block_mask(layout.action_slices, layout.action_dim)
            in_mask = np.concatenate([obs_mask, act_mask], axis=1)
        in_mask = np.tile(in_mask, (n_critics * n_runs, 1))
        group_runs = np.tile(np.repeat(np.arange(n_runs), layout.n_agents), n_critics)
        self.q_net = GroupedMLP(
            in_mask,
            net_arch,
            np.ones((len(in_mask), 1), dtype=np.float32),
            activation_fn,
            group_runs=group_runs,
            generators=generators,
            group_blocks=np.repeat(np.arange(n_critics * n_runs), layout.n_agents),  # one block per (critic, run)
        )

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        :param obs: (n_runs, batch, obs_dim) joint observations (or (batch, obs_dim) for one run).
        :param actions: (n_runs, batch, action_dim) joint actions (or (batch, action_dim)).
        :return: Q-values of shape (n_critics, n_runs, n_agents, batch).
        """
        x = _split_runs(th.cat([obs, actions], dim=-1), self.n_runs)
        runs, batch, dim = x.shape
        groups = self.n_critics * runs * self.n_agents
        x = x.unsqueeze(0).unsqueeze(2).expand(self.n_critics, runs, self.n_agents, batch, dim).reshape(groups, batch, dim)
        return self.q_net(x).view(self.n_critics, runs, self.n_agents, batch)

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor, detach_params: bool = False) -> th.Tensor:
        """
        First critic of each agent, where agent ``i``'s critic gets its own row of ``actions``.

        :param obs: (n_runs, batch, obs_dim) joint observations.
        :param actions: (n_runs, n_agents, batch, action_dim) joint actions, one per agent.
        :param detach_params: Do not record gradients for the critic's parameters.
        :return: (n_runs, n_agents, batch)
        """
        runs, batch, _ = obs.shape
        x = th.cat([obs.unsqueeze(1).expand(runs, self.n_agents, batch, obs.shape[-1]), actions], dim=-1)
        x = x.reshape(runs * self.n_agents, batch, x.shape[-1])
        q = self.q_net(x, groups=slice(0, runs * self.n_agents), detach_params=detach_params)
        return q.view(runs, self.n_agents, batch)


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
    :param n_runs: Independent runs packed in the stacked tensors (set by MADDPG; 1 for an ordinary model).
    :param run_seeds: Seed of each run's initial weights (set by MADDPG; None: torch's global generator).
    :param normalize_images: Must be False (accepted so that SB3's ``BasePolicy.load`` can rebuild the policy).
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
        n_runs: int = 1,
        run_seeds: list[int] | None = None,
        normalize_images: bool = False,
    ):
        if normalize_images:
            raise ValueError("MADDPGPolicy works on vector observations: normalize_images must be False")
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
        if n_runs < 1 or (run_seeds is not None and len(run_seeds) != n_runs):
            raise ValueError(f"n_runs must be >= 1 with one seed per run; got n_runs={n_runs}, run_seeds={run_seeds}")
        self.n_runs = n_runs
        self.run_seeds = None if run_seeds is None else [int(seed) for seed in run_seeds]
        self._actor_kwargs = dict(layout=agent_layout, net_arch=actor_arch, activation_fn=activation_fn, n_runs=n_runs)
        self._critic_kwargs = dict(
            layout=agent_layout,
            net_arch=critic_arch,
            activation_fn=activation_fn,
            n_critics=n_critics,
            centralized=centralized_critic,
            n_runs=n_runs,
        )
        self._build(lr_schedule)

    def _build(self, lr_schedule: Schedule) -> None:
        # each run draws its actors' then its critics' weights from its own generator, whatever it is packed with
        generators = _generators(self.run_seeds)
        self.actor = MultiAgentActor(**self._actor_kwargs, generators=generators)
        self.actor_target = MultiAgentActor(**self._actor_kwargs)
        self.actor_target.load_state_dict(self.actor.state_dict())
        self.critic = MultiAgentCritic(**self._critic_kwargs, generators=generators)
        self.critic_target = MultiAgentCritic(**self._critic_kwargs)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.actor_target.requires_grad_(False)
        self.critic_target.requires_grad_(False)
        self.actor.optimizer = self._make_optimizer(self.actor.mu, lr_schedule)
        self.critic.optimizer = self._make_optimizer(self.critic.q_net, lr_schedule)
        self.set_training_mode(False)

    def _make_optimizer(self, net: GroupedMLP, lr_schedule: Schedule) -> th.optim.Optimizer:
        kwargs = dict(self.optimizer_kwargs)
        if self.optimizer_class is th.optim.Adam and not ({"fused", "foreach"} & set(kwargs)):
            # Adam's fused kernel, given each run's block of the stacked tensors separately, so that a run is
            # updated the same way alone or in a pack
            blocks = [net.block_bounds for _ in net.parameters()]
            return BlockAdam(net.parameters(), blocks=blocks, lr=lr_schedule(1), **kwargs)
        return self.optimizer_class(net.parameters(), lr=lr_schedule(1), **kwargs)  # type: ignore[call-arg]

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
                n_runs=self.n_runs,
                run_seeds=self.run_seeds,
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

