"""Per-agent actors and critics of MADDPG, held as stacked tensors so that all agents run in one batched pass."""

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_macb.common.block_adam import BlockAdam
from sb3_macb.common.grouped_mlp import LARGE_LAYER_PATHS, PRECISIONS, GroupedMLP
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


class _SharedInputs:
    """
    Index tables for agents that share networks: each agent's own slice of a vector (padded to the widest agent) and
    its one-hot id within its sharing group, so that agents of a group feed the same weight columns.

    :param slices: Each agent's slice of the input vector (observation or, for outputs, action).
    :param groups: Sharing groups (lists of agent indices; every agent in exactly one).
    """

    def __init__(self, slices: list[slice], groups: list[list[int]]):
        n_agents = len(slices)
        self.group_of = np.zeros(n_agents, dtype=np.int64)
        position = np.zeros(n_agents, dtype=np.int64)
        for p, group in enumerate(groups):
            for k, agent in enumerate(group):
                self.group_of[agent], position[agent] = p, k
        shared = [len(groups[self.group_of[i]]) > 1 for i in range(n_agents)]
        self.n_ids = max((len(g) for g in groups if len(g) > 1), default=0)
        self.width = max(sl.stop - sl.start for sl in slices)
        total = max(sl.stop for sl in slices)
        self.gather = np.full((n_agents, self.width), total, dtype=np.int64)  # `total`: an appended zero column
        for i, sl in enumerate(slices):
            self.gather[i, : sl.stop - sl.start] = np.arange(sl.start, sl.stop)
        self.ids = np.zeros((n_agents, self.n_ids), dtype=np.float32)
        for i in range(n_agents):
            if shared[i]:
                self.ids[i, position[i]] = 1.0
        # per group: the columns its members use (own slice, then the id if the group is shared)
        self.masks = np.zeros((len(groups), self.width + self.n_ids), dtype=np.float32)
        for p, group in enumerate(groups):
            size = slices[group[0]].stop - slices[group[0]].start
            self.masks[p, :size] = 1.0
            if len(group) > 1:
                self.masks[p, self.width :] = 1.0
        # where each column of the joint vector comes from in the agents' padded outputs
        self.scatter = np.zeros(total, dtype=np.int64)
        for i, sl in enumerate(slices):
            self.scatter[sl] = i * self.width + np.arange(sl.stop - sl.start)


def check_share_groups(layout: AgentLayout, groups: list[list[int]]) -> None:
    """Raise a clear error unless every agent is in exactly one group and a group's agents have equal spaces."""
    seen = sorted(i for g in groups for i in g)
    if seen != list(range(layout.n_agents)):
        raise ValueError(f"Sharing groups must hold every agent exactly once, got {groups} for {layout.n_agents} agents")
    for group in groups:
        spec = {(layout.obs_dims[i], layout.action_dims[i], layout.discrete_agents[i]) for i in group}
        if len(spec) > 1:
            names = [layout.agents[i] for i in group]
            raise ValueError(
                f"Agents {names} cannot share networks: their (observation size, action size, discrete) differ: {sorted(spec)}"
            )


class MultiAgentActor(nn.Module):
    """
    One deterministic actor per agent (and per run of a pack), each reading its own observation; the output is
    the joint action in [-1, 1], each agent writing its own slice. Group ``r * n_agents + i`` is agent ``i`` of run
    ``r``. A continuous agent's slice is ``tanh`` of its outputs; a discrete agent's outputs are logits, and its
    slice is the one-hot action (scaled to -1/1) of their argmax, or, given Gumbel noise, of a Gumbel-max sample,
    with the straight-through Gumbel-softmax gradient for training (as the MADDPG paper trains discrete actions).

    :param layout: The agents' observation and action sizes.
    :param net_arch: Hidden layer sizes of each actor.
    :param activation_fn: Activation function.
    :param n_runs: Independent runs whose actors are stacked together (1: an ordinary model).
    :param generators: One torch generator per run for the initial weights (None: the global one).
    :param gumbel_temperature: Temperature of the Gumbel-softmax relaxation of discrete actions.
    :param share_groups: Agents that share one actor (lists of agent indices, every agent in one; None: no sharing).
        A shared actor reads its agent's own observation followed by the agent's one-hot id within the group.
    :param precision: Precision of the products (``"fp32"`` or ``"bf16"``, see :class:`GroupedMLP`).
    :param large_layers: ``"per_group"`` or ``"batched"`` products of networks with a large layer (see :class:`GroupedMLP`).
    """

    mu: GroupedMLP
    optimizer: th.optim.Optimizer  # (set by MADDPGPolicy)
    # buffers (registered in __init__; the sharing and discrete ones only where they apply)
    obs_gather: th.Tensor
    agent_ids: th.Tensor
    action_scatter: th.Tensor
    discrete_mask: th.Tensor
    pad_idx: th.Tensor
    pad_fill: th.Tensor
    pad_valid: th.Tensor
    discrete_dims: th.Tensor

    def __init__(
        self,
        layout: AgentLayout,
        net_arch: list[int],
        activation_fn: type[nn.Module] = nn.ReLU,
        n_runs: int = 1,
        generators: list[th.Generator] | None = None,
        gumbel_temperature: float = 1.0,
        share_groups: list[list[int]] | None = None,
        precision: str = "fp32",
        large_layers: str = "per_group",
    ):
        super().__init__()
        self.n_agents = layout.n_agents
        self.n_runs = n_runs
        self.gumbel_temperature = gumbel_temperature
        self.shared: _SharedInputs | None = None
        if share_groups is None:
            self.mu = GroupedMLP(
                np.tile(_block_mask(layout.obs_slices, layout.obs_dim), (n_runs, 1)),
                net_arch,
                np.tile(_block_mask(layout.action_slices, layout.action_dim), (n_runs, 1)),
                activation_fn,
                group_runs=np.repeat(np.arange(n_runs), layout.n_agents),
                generators=generators,
                precision=precision,
                large_layers=large_layers,
            )
        else:
            check_share_groups(layout, share_groups)
            self.shared = shared = _SharedInputs(layout.obs_slices, share_groups)
            outputs = _SharedInputs(layout.action_slices, share_groups)
            n_groups = len(share_groups)
            self.mu = GroupedMLP(
                np.tile(shared.masks, (n_runs, 1)),
                net_arch,
                np.tile(outputs.masks[:, : outputs.width], (n_runs, 1)),
                activation_fn,
                group_runs=np.repeat(np.arange(n_runs), n_groups),
                generators=generators,
                param_index=(np.arange(n_runs)[:, None] * n_groups + shared.group_of[None, :]).ravel(),
                precision=precision,
                large_layers=large_layers,
            )
            self.register_buffer("obs_gather", th.as_tensor(shared.gather), persistent=False)
            self.register_buffer("agent_ids", th.as_tensor(shared.ids), persistent=False)
            self.register_buffer("action_scatter", th.as_tensor(outputs.scatter), persistent=False)
            self.action_width = outputs.width
        mask = layout.discrete_action_mask
        self.has_discrete = bool(mask.any())
        self.register_buffer("discrete_mask", th.as_tensor(mask), persistent=False)
        # discrete agents' logits gathered into a padded (n_discrete_agents, max_n) grid, so that softmax and argmax
        # run for all of them at once
        slices = [sl for sl, flag in zip(layout.action_slices, layout.discrete_agents) if flag]
        width = max((sl.stop - sl.start for sl in slices), default=0)
        pad_idx = np.zeros((len(slices), width), dtype=np.int64)
        valid = np.zeros((len(slices), width), dtype=bool)
        for row, sl in enumerate(slices):
            pad_idx[row, : sl.stop - sl.start] = np.arange(sl.start, sl.stop)
            valid[row, : sl.stop - sl.start] = True
        self.discrete_shape = (len(slices), width)
        self.register_buffer("pad_idx", th.as_tensor(pad_idx.ravel()), persistent=False)
        self.register_buffer("pad_fill", th.as_tensor(np.where(valid, 0.0, -np.inf).astype(np.float32)), persistent=False)
        self.register_buffer("pad_valid", th.as_tensor(np.flatnonzero(valid.ravel())), persistent=False)
        self.register_buffer("discrete_dims", th.as_tensor(np.flatnonzero(mask)), persistent=False)

    def raw(self, obs: th.Tensor) -> th.Tensor:
        """The actors' outputs before squashing (logits for discrete agents), of the joint action's shape."""
        x = _split_runs(obs, self.n_runs)
        runs, batch, dim = x.shape
        if self.shared is not None:
            padded = th.cat([x, x.new_zeros(runs, batch, 1)], dim=-1)[..., self.obs_gather]  # (runs, batch, agents, w)
            ids = self.agent_ids.expand(runs, batch, *self.agent_ids.shape)
            inputs = th.cat([padded, ids], dim=-1).transpose(1, 2).reshape(runs * self.n_agents, batch, -1)
            out = self.mu(inputs).view(runs, self.n_agents, batch, self.action_width).transpose(1, 2)
            out = out.reshape(runs, batch, -1)[..., self.action_scatter]
            return out if obs.dim() == 3 else out.reshape(obs.shape[0], -1)
        x = x.unsqueeze(1).expand(runs, self.n_agents, batch, dim).reshape(runs * self.n_agents, batch, dim)
        # each agent writes its own slice (the others' outputs are exact zeros): the sum assembles the joint action
        out = self.mu(x).view(runs, self.n_agents, batch, -1).sum(dim=1)
        return out if obs.dim() == 3 else out.reshape(obs.shape[0], -1)

    def forward(self, obs: th.Tensor, gumbel: th.Tensor | None = None, straight_through: bool = False) -> th.Tensor:
        """
        :param obs: (n_runs, batch, obs_dim), or (n_runs * n, obs_dim) with the runs' rows one run after another.
        :param gumbel: Gumbel(0, 1) noise of the joint action's shape, added to discrete agents' logits (a sample
            of their policy); None: their argmax (the deterministic policy).
        :param straight_through: Discrete agents' one-hot actions carry the Gumbel-softmax gradient.
        :return: Joint actions in [-1, 1], of the same leading shape as ``obs``.
        """
        if not self.has_discrete and self.shared is None:
            x = _split_runs(obs, self.n_runs)
            runs, batch, dim = x.shape
            x = x.unsqueeze(1).expand(runs, self.n_agents, batch, dim).reshape(runs * self.n_agents, batch, dim)
            out = self.mu(x)
            action = th.tanh(out.view(runs, self.n_agents, batch, -1).sum(dim=1))
            return action if obs.dim() == 3 else action.reshape(obs.shape[0], -1)
        return self.squash(self.raw(obs), gumbel, straight_through)

    def squash(self, raw: th.Tensor, gumbel: th.Tensor | None = None, straight_through: bool = False) -> th.Tensor:
        """Actions in [-1, 1] from :meth:`raw` outputs (see :meth:`forward`)."""
        continuous = th.tanh(raw)
        if not self.has_discrete:
            return continuous
        logits = raw if gumbel is None else raw + gumbel
        grid = logits.index_select(-1, self.pad_idx).view(*logits.shape[:-1], *self.discrete_shape) + self.pad_fill
        hard = nn.functional.one_hot(grid.argmax(dim=-1), grid.shape[-1]).to(raw.dtype)  # (..., n_discrete, max_n)
        if straight_through:
            soft = th.softmax(grid / self.gumbel_temperature, dim=-1)
            hard = hard - soft.detach() + soft
        one_hot = hard.flatten(-2).index_select(-1, self.pad_valid)  # (..., n_discrete_dims), as discrete_dims
        scattered = continuous.new_zeros(continuous.shape).index_copy(-1, self.discrete_dims, 2.0 * one_hot - 1.0)
        return th.where(self.discrete_mask, scattered, continuous)


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
    :param share_groups: Agents that share one critic (lists of agent indices; None: no sharing).
    :param precision: Precision of the products (``"fp32"`` or ``"bf16"``, see :class:`GroupedMLP`).
    :param large_layers: ``"per_group"`` or ``"batched"`` products of networks with a large layer (see :class:`GroupedMLP`).
    """

    q_net: GroupedMLP
    optimizer: th.optim.Optimizer  # (set by MADDPGPolicy)
    agent_ids: th.Tensor  # buffer of shared critics

    def __init__(
        self,
        layout: AgentLayout,
        net_arch: list[int],
        activation_fn: type[nn.Module] = nn.ReLU,
        n_critics: int = 1,
        centralized: bool = True,
        n_runs: int = 1,
        generators: list[th.Generator] | None = None,
        share_groups: list[list[int]] | None = None,
        precision: str = "fp32",
        large_layers: str = "per_group",
    ):
        super().__init__()
        self.n_agents = layout.n_agents
        self.n_critics = n_critics
        self.n_runs = n_runs
        n_in = layout.obs_dim + layout.action_dim
        self.n_ids = 0
        param_index = None
        n_params = layout.n_agents  # parameter groups per (critic, run)
        if share_groups is not None:
            if not centralized:
                raise ValueError("Critics can be shared only when they are centralized (centralized_critic=True)")
            check_share_groups(layout, share_groups)
            shared = _SharedInputs(layout.obs_slices, share_groups)
            self.n_ids, n_params = shared.n_ids, len(share_groups)
            in_mask = np.ones((n_params, n_in + self.n_ids), dtype=np.float32)
            in_mask[:, n_in:] = shared.masks[:, shared.width :]  # the id columns, for shared groups only
            param_index = (np.arange(n_critics * n_runs)[:, None] * n_params + shared.group_of[None, :]).ravel()
            self.register_buffer("agent_ids", th.as_tensor(shared.ids), persistent=False)
        elif centralized:
            in_mask = np.ones((layout.n_agents, n_in), dtype=np.float32)
        else:
            obs_mask = _block_mask(layout.obs_slices, layout.obs_dim)
            act_mask = _block_mask(layout.action_slices, layout.action_dim)
            in_mask = np.concatenate([obs_mask, act_mask], axis=1)
        in_mask = np.tile(in_mask, (n_critics * n_runs, 1))
        group_runs = np.tile(np.repeat(np.arange(n_runs), n_params), n_critics)
        self.q_net = GroupedMLP(
            in_mask,
            net_arch,
            np.ones((len(in_mask), 1), dtype=np.float32),
            activation_fn,
            group_runs=group_runs,
            generators=generators,
            group_blocks=np.repeat(np.arange(n_critics * n_runs), n_params),  # one block per (critic, run)
            param_index=param_index,
            precision=precision,
            large_layers=large_layers,
        )

    def _with_ids(self, x: th.Tensor) -> th.Tensor:
        """(..., n_agents, batch, dim) inputs with each agent's one-hot id appended (shared critics)."""
        if not self.n_ids:
            return x
        ids = self.agent_ids.unsqueeze(-2).expand(*x.shape[:-1], self.n_ids)
        return th.cat([x, ids], dim=-1)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """
        :param obs: (n_runs, batch, obs_dim) joint observations (or (batch, obs_dim) for one run).
        :param actions: (n_runs, batch, action_dim) joint actions (or (batch, action_dim)).
        :return: Q-values of shape (n_critics, n_runs, n_agents, batch).
        """
        x = _split_runs(th.cat([obs, actions], dim=-1), self.n_runs)
        runs, batch, dim = x.shape
        groups = self.n_critics * runs * self.n_agents
        x = self._with_ids(x.unsqueeze(0).unsqueeze(2).expand(self.n_critics, runs, self.n_agents, batch, dim))
        return self.q_net(x.reshape(groups, batch, -1)).view(self.n_critics, runs, self.n_agents, batch)

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor, detach_params: bool = False) -> th.Tensor:
        """
        First critic of each agent, where agent ``i``'s critic gets its own row of ``actions``.

        :param obs: (n_runs, batch, obs_dim) joint observations.
        :param actions: (n_runs, n_agents, batch, action_dim) joint actions, one per agent.
        :param detach_params: Do not record gradients for the critic's parameters.
        :return: (n_runs, n_agents, batch)
        """
        runs, batch, _ = obs.shape
        x = self._with_ids(th.cat([obs.unsqueeze(1).expand(runs, self.n_agents, batch, obs.shape[-1]), actions], dim=-1))
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
    :param share_actors: Groups of agent indices that share one actor (set by MADDPG from ``share_parameters``).
    :param share_critics: Groups of agent indices that share one critic (set by MADDPG with ``share_critics``).
    :param precision: ``"fp32"`` (default) or ``"bf16"``: the networks' products in bfloat16 from float32 master
        weights, gradients and optimizer state. Opt-in, for CPUs with native bfloat16 GEMMs (AVX-512 BF16, AMX) and
        large networks; see ``benchmarks/throughput.py --bf16`` for its speed on the machine at hand.
    :param large_layers: ``"per_group"`` (default) or ``"batched"``: how networks with a large layer (e.g. 400-300)
        compute their products on the CPU (see :class:`~sb3_macb.common.grouped_mlp.GroupedMLP`); the faster one
        depends on the CPU (``benchmarks/update_paths.py``), and they agree up to float32 rounding.
    :param intrinsic_critic: Also build a second set of critics (``critic_int``, its target and optimizer), the
        same architecture as the critics, that learns the exploration bonus's return (set by MADDPG).
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
        share_actors: list[list[int]] | None = None,
        share_critics: list[list[int]] | None = None,
        precision: str = "fp32",
        intrinsic_critic: bool = False,
        large_layers: str = "per_group",
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
        self.share_actors, self.share_critics = share_actors, share_critics
        if precision not in PRECISIONS:
            raise ValueError(f"policy_kwargs precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        if large_layers not in LARGE_LAYER_PATHS:
            raise ValueError(f"policy_kwargs large_layers must be one of {list(LARGE_LAYER_PATHS)}, got {large_layers!r}")
        self.large_layers = large_layers
        self.intrinsic_critic = bool(intrinsic_critic)
        self._actor_kwargs: dict[str, Any] = dict(
            layout=agent_layout,
            net_arch=actor_arch,
            activation_fn=activation_fn,
            n_runs=n_runs,
            share_groups=share_actors,
            precision=precision,
            large_layers=large_layers,
        )
        self._critic_kwargs: dict[str, Any] = dict(
            layout=agent_layout,
            net_arch=critic_arch,
            activation_fn=activation_fn,
            n_critics=n_critics,
            centralized=centralized_critic,
            n_runs=n_runs,
            share_groups=share_critics,
            precision=precision,
            large_layers=large_layers,
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
        self.critic_int: MultiAgentCritic | None = None
        self.critic_int_target: MultiAgentCritic | None = None
        if self.intrinsic_critic:  # drawn after the others: actors and critics start as they would without it
            self.critic_int = MultiAgentCritic(**self._critic_kwargs, generators=generators)
            self.critic_int_target = MultiAgentCritic(**self._critic_kwargs)
            self.critic_int_target.load_state_dict(self.critic_int.state_dict())
            self.critic_int_target.requires_grad_(False)
            self.critic_int.optimizer = self._make_optimizer(self.critic_int.q_net, lr_schedule)
        self.set_training_mode(False)

    def _make_optimizer(self, net: GroupedMLP, lr_schedule: Schedule) -> th.optim.Optimizer:
        kwargs = dict(self.optimizer_kwargs)
        if self.optimizer_class is th.optim.Adam and not ({"fused", "foreach"} & set(kwargs)):
            # Adam's fused kernel, given each run's block of the stacked tensors separately, so that a run is
            # updated the same way alone or in a pack
            blocks: list[list[tuple[int, int]] | None] = [net.block_bounds for _ in net.parameters()]
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
                share_actors=self.share_actors,
                share_critics=self.share_critics,
                precision=self.precision,
                intrinsic_critic=self.intrinsic_critic,
                large_layers=self.large_layers,
            )
        )
        return data

    def forward(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return self._predict(observation, deterministic=deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        # MADDPG actors are deterministic: exploration comes from action noise
        return self.actor(observation)

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
            if self.__dict__.get("intrinsic_critic"):
                modules += list(self.critic_int.modules())  # type: ignore[union-attr]
            self.__dict__["_mode_modules"] = modules
        for module in modules:
            module.__dict__["training"] = mode
        self.__dict__["training"] = mode


MlpPolicy = MADDPGPolicy
