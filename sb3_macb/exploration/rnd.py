"""RND: Random Network Distillation as an exploration bonus, in the slot MACB's count bonus takes."""

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from torch import nn

from sb3_macb.envs.joint_env import AgentLayout
from sb3_macb.exploration.normalize import NORMALIZE_MODES, BonusNormalizer

RND_SCOPES = ("joint", "local")


def _mlp(sizes: list[int], generator: th.Generator) -> nn.Sequential:
    """ReLU MLP with weights drawn from ``generator`` (uniform in +-1/sqrt(fan_in), as torch's default)."""
    layers: list[nn.Module] = []
    for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        linear = nn.Linear(n_in, n_out)
        bound = 1.0 / np.sqrt(n_in)
        with th.no_grad():
            linear.weight.copy_(th.rand(n_out, n_in, generator=generator) * 2 * bound - bound)
            linear.bias.copy_(th.rand(n_out, generator=generator) * 2 * bound - bound)
        layers.append(linear)
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class RND:
    """
    Random Network Distillation (Burda et al., 2018, https://arxiv.org/abs/1810.12894) as an exploration bonus: a
    fixed, randomly initialised target network and a predictor trained to match it, both over the joint observation
    (``scope="joint"``, one bonus shared by all agents) or over each agent's own observation (``"local"``, each
    agent's critic getting its own). The bonus of a sampled transition is ``beta`` times the predictor's squared
    error on its observation, taken when the minibatch is sampled (never stored); the predictor then takes one Adam
    step on that minibatch. States the predictor has been trained on give small errors; new ones give large errors.

    Pass it to MADDPG as ``exploration=RND(...)``, or in the zoo YAML as ``exploration: {estimator: rnd, ...}``. Each
    run of a pack has its own networks and optimizer (drawn from the run's seed), so a packed run is its solo run.

    :param beta: Bonus coefficient (>= 0), or a schedule of the progress remaining (as :class:`~sb3_macb.MACB`).
    :param scope: ``"joint"`` or ``"local"``.
    :param net_arch: Hidden sizes of the target and the predictor.
    :param embedding_dim: Output size of both networks.
    :param learning_rate: The predictor's Adam learning rate.
    :param normalize: How the error enters the update: ``"zscore"`` (the default; the RND paper divides its bonus by
        a running standard deviation), ``"center"`` or None (the raw error times ``beta``). See
        :class:`~sb3_macb.exploration.normalize.BonusNormalizer`.
    :param normalize_rate: Weight of each sampled minibatch in the running statistics, in (0, 1].
    :param std_floor: The smallest standard deviation ``"zscore"`` divides by.
    :param seed: Seed of the networks' weights; None: the model's seed.
    """

    counts = True  # (the bonus varies: not the constant-bonus control)

    def __init__(
        self,
        beta: float | Callable[[float], float] = 0.8,
        scope: str = "joint",
        net_arch: list[int] | None = None,
        embedding_dim: int = 32,
        learning_rate: float = 1e-3,
        normalize: str | None = "zscore",
        normalize_rate: float = 0.01,
        std_floor: float = 0.01,
        seed: int | None = None,
    ):
        from sb3_macb.exploration.macb import MACB

        try:  # the same checks of the settings the two share
            MACB(beta=beta, normalize=normalize, normalize_rate=normalize_rate, std_floor=std_floor)
        except ValueError as exc:
            raise ValueError(str(exc).replace("MACB:", "RND:", 1)) from None
        if scope not in RND_SCOPES:
            raise ValueError(f"RND: unknown scope {scope!r}; expected one of {RND_SCOPES}")
        net_arch = [64, 64] if net_arch is None else list(net_arch)
        if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in net_arch):
            raise ValueError(f"RND: net_arch must be a list of layer sizes (integers >= 1), got {net_arch!r}")
        if isinstance(embedding_dim, bool) or not isinstance(embedding_dim, int) or embedding_dim < 1:
            raise ValueError(f"RND: embedding_dim must be an integer >= 1, got {embedding_dim!r}")
        if isinstance(learning_rate, bool) or not isinstance(learning_rate, (int, float)) or not learning_rate > 0:
            raise ValueError(f"RND: learning_rate must be a number > 0, got {learning_rate!r}")
        if normalize not in NORMALIZE_MODES:
            raise ValueError(f"RND: normalize must be one of {NORMALIZE_MODES}, got {normalize!r}")
        self.beta = beta if callable(beta) else float(beta)
        self.scope = scope
        self.net_arch = net_arch
        self.embedding_dim = int(embedding_dim)
        self.learning_rate = float(learning_rate)
        self.normalize = normalize
        self.normalize_rate = float(normalize_rate)
        self.std_floor = float(std_floor)
        self.seed = seed
        self.normalizer = BonusNormalizer(normalize, normalize_rate, std_floor) if normalize is not None else None
        self.progress_remaining = 1.0
        self.total_count = 0
        self._layout: AgentLayout | None = None
        self.targets: list[nn.Module] = []
        self.predictors: list[nn.Module] = []
        self.optimizer: th.optim.Optimizer | None = None

    def __repr__(self) -> str:
        return (f"RND(beta={self.beta}, scope={self.scope!r}, net_arch={self.net_arch}, embedding_dim={self.embedding_dim}, "
                f"learning_rate={self.learning_rate}, normalize={self.normalize!r}, seed={self.seed})")  # fmt: skip

    @property
    def config(self) -> dict[str, Any]:
        """The settings, as plain values (what ``RND(**config)`` takes)."""
        return {"beta": self.beta, "scope": self.scope, "net_arch": self.net_arch, "embedding_dim": self.embedding_dim,
                "learning_rate": self.learning_rate, "normalize": self.normalize, "normalize_rate": self.normalize_rate,
                "std_floor": self.std_floor, "seed": self.seed}  # fmt: skip

    @property
    def current_beta(self) -> float:
        return float(self.beta(self.progress_remaining)) if callable(self.beta) else self.beta

    # --- what the replay buffer and MADDPG ask of an estimator (as of MACB) ---------------------------------------

    @property
    def is_setup(self) -> bool:
        return self._layout is not None and bool(self.predictors)

    @property
    def n_tables(self) -> int:
        """Bonus columns: one per agent for ``scope="local"``, else one shared by all agents."""
        if self._layout is None:
            return 0
        return self._layout.n_agents if self.scope == "local" else 1

    uses_observations = True  # the replay buffer passes each sampled minibatch's observations to :meth:`bonus`
    num_codes = 0  # (MACB's table statistics, logged for every estimator: none here)
    count1_fraction = 0.0

    @property
    def nbytes(self) -> int:
        return sum(p.numel() * p.element_size() for net in (*self.targets, *self.predictors) for p in net.parameters())

    def setup(self, layout: AgentLayout, seed: int | None = None) -> None:
        """Draw the target and predictor networks for this agent layout (done by MADDPG)."""
        if self.is_setup and self._layout == layout:
            return
        if self.seed is None:
            self.seed = int(seed) if seed is not None else int(np.random.SeedSequence().entropy) % (2**31)  # type: ignore[arg-type]
        generator = th.Generator().manual_seed(int(self.seed))
        self._layout = layout
        dims = list(layout.obs_dims) if self.scope == "local" else [layout.obs_dim]
        sizes = [[d, *self.net_arch, self.embedding_dim] for d in dims]
        self.targets = [_mlp(s, generator).requires_grad_(False) for s in sizes]
        self.predictors = [_mlp(s, generator) for s in sizes]
        params = [p for net in self.predictors for p in net.parameters()]
        self.optimizer = th.optim.Adam(params, lr=self.learning_rate, foreach=False)

    def keys(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Nothing to store beside a transition: zeros, (n, n_tables)."""
        return np.zeros((len(obs), self.n_tables), dtype=np.uint64)

    def count(self, keys: np.ndarray) -> None:
        """Collected transitions are only counted (the predictor learns from sampled minibatches)."""
        self.total_count += len(keys)

    def _inputs(self, observations: np.ndarray) -> list[th.Tensor]:
        obs = th.as_tensor(np.asarray(observations, dtype=np.float32))
        if self.scope == "local":
            assert self._layout is not None
            return [obs[:, s] for s in self._layout.obs_slices]
        return [obs]

    def errors(self, observations: np.ndarray) -> np.ndarray:
        """The predictor's squared error on each observation, (n, n_tables) float64 (nothing is trained)."""
        with th.no_grad():
            return np.stack(
                [
                    (p(x) - t(x)).pow(2).mean(dim=1).double().numpy()
                    for x, p, t in zip(self._inputs(observations), self.predictors, self.targets)
                ],
                axis=1,
            )

    def bonus(self, keys: np.ndarray, training: bool = True, observations: np.ndarray | None = None) -> np.ndarray:
        """
        The bonus of a sampled minibatch: ``beta`` times the (normalised) prediction errors of its observations;
        with ``training`` the predictor then takes one Adam step on them.

        :param keys: (n, n_tables) stored keys (unused: zeros).
        :param training: Train the predictor and update the normalisation statistics.
        :param observations: (n, obs_dim) joint observations of the minibatch.
        :return: (n, n_tables) float32.
        """
        if observations is None:
            raise ValueError("RND's bonus needs the minibatch's observations")
        inputs = self._inputs(observations)
        predictions = [p(x) for x, p in zip(inputs, self.predictors)]
        with th.no_grad():
            targets = [t(x) for x, t in zip(inputs, self.targets)]
        losses = [(p - t).pow(2).mean(dim=1) for p, t in zip(predictions, targets)]
        errors = np.stack([loss.detach().double().numpy() for loss in losses], axis=1)
        if training:
            assert self.optimizer is not None
            self.optimizer.zero_grad(set_to_none=True)
            th.stack([loss.mean() for loss in losses]).sum().backward()
            self.optimizer.step()
        scaled = errors if self.normalizer is None else self.normalizer(errors, training)
        return (self.current_beta * scaled).astype(np.float32)

    # --- saving: settings are pickled with the model, the networks and optimizer go to its torch variables --------

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["targets"], state["predictors"], state["optimizer"], state["_layout"] = [], [], None, None
        return state

    def __deepcopy__(self, memo: dict) -> "RND":
        clone = RND.__new__(RND)
        clone.__dict__.update(copy.deepcopy(self.__getstate__(), memo))
        return clone

    def state_dict(self) -> dict[str, th.Tensor]:
        """The networks, the predictor's Adam state and the running statistics, as tensors."""
        tensors: dict[str, th.Tensor] = {"total_count": th.tensor(self.total_count, dtype=th.int64)}
        for kind, nets in (("target", self.targets), ("predictor", self.predictors)):
            for i, net in enumerate(nets):
                tensors.update({f"{kind}_{i}.{name}": t.detach().clone() for name, t in net.state_dict().items()})
        assert self.optimizer is not None
        for j, state in self.optimizer.state_dict()["state"].items():
            tensors.update({f"adam_{j}.{name}": th.as_tensor(v).clone() for name, v in state.items()})
        if self.normalizer is not None:
            tensors.update({f"normalizer.{name}": t for name, t in self.normalizer.state_dict().items()})
        return tensors

    def load_state_dict(self, state: dict[str, th.Tensor], strict: bool = True) -> None:
        """Restore what :meth:`state_dict` returned (after :meth:`setup`)."""
        for kind, nets in (("target", self.targets), ("predictor", self.predictors)):
            for i, net in enumerate(nets):
                prefix = f"{kind}_{i}."
                net.load_state_dict({name[len(prefix) :]: t for name, t in state.items() if name.startswith(prefix)})
        assert self.optimizer is not None
        saved = self.optimizer.state_dict()
        adam: dict[int, dict[str, th.Tensor]] = {}
        for name, t in state.items():
            if name.startswith("adam_"):
                index, key = name[len("adam_") :].split(".", 1)
                adam.setdefault(int(index), {})[key] = t.clone()
        saved["state"] = adam
        self.optimizer.load_state_dict(saved)
        self.total_count = int(state["total_count"])
        if self.normalizer is not None:
            self.normalizer.load_state_dict(
                {name[len("normalizer.") :]: t for name, t in state.items() if name.startswith("normalizer.")}
            )
