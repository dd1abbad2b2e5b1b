"""sb3_macb: multi-agent algorithms (MADDPG, MATD3) and count-based exploration (MACB) for Stable-Baselines3."""

from sb3_macb.buffers import MACBReplayBuffer, MultiAgentReplayBuffer
from sb3_macb.envs import AgentLayout, JointEnv, make_joint_env
from sb3_macb.exploration import MACB, RND
from sb3_macb.maddpg import MADDPG, MADDPGPolicy, MlpPolicy
from sb3_macb.matd3 import MATD3

__version__ = "0.13.0"

__all__ = [
    "MACB",
    "MADDPG",
    "MATD3",
    "RND",
    "MACBReplayBuffer",
    "AgentLayout",
    "JointEnv",
    "MADDPGPolicy",
    "MlpPolicy",
    "MultiAgentReplayBuffer",
    "__version__",
    "make_joint_env",
]
