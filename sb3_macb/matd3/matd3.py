"""MATD3: MADDPG with TD3's clipped double Q-learning, delayed policy updates and target policy smoothing."""

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv

from sb3_macb.maddpg.maddpg import MADDPG
from sb3_macb.maddpg.policies import MADDPGPolicy


class MATD3(MADDPG):
    """
    Multi-Agent TD3 (MATD3): MADDPG whose agents each have two centralized critics, learn from the smaller of their
    two target values, update their actors and targets every ``policy_delay`` critic updates, and smooth the target
    policy with clipped Gaussian noise. Everything else (environments, packs, sharing, exploration, saving) is
    :class:`~sb3_macb.MADDPG`'s, whose keyword arguments it takes.

    Paper: https://arxiv.org/abs/1910.01465 (TD3: https://arxiv.org/abs/1802.09477)

    :param policy: The policy model to use (``"MlpPolicy"``).
    :param env: The environment to learn from: a joint env, a PettingZoo env, or a registered env id.
    :param policy_delay: Update the actors and target networks every ``policy_delay`` critic updates.
    :param target_policy_noise: Standard deviation of the target policy smoothing noise.
    :param target_noise_clip: Limit for the absolute value of the target policy smoothing noise.
    :param policy_kwargs: Policy arguments; ``n_critics`` defaults to 2 (clipped double Q-learning).
    :param kwargs: Every other argument of :class:`~sb3_macb.MADDPG`.
    """

    def __init__(
        self,
        policy: str | type[MADDPGPolicy],
        env: GymEnv | str,
        policy_delay: int = 2,
        target_policy_noise: float = 0.2,
        target_noise_clip: float = 0.5,
        policy_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ):
        policy_kwargs = {"n_critics": 2, **(policy_kwargs or {})}
        super().__init__(
            policy,
            env,
            policy_delay=policy_delay,
            target_policy_noise=target_policy_noise,
            target_noise_clip=target_noise_clip,
            policy_kwargs=policy_kwargs,
            **kwargs,
        )
