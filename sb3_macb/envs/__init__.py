from sb3_macb.envs import communicative_navigation_v0, sparse_spread_v0, two_agent_navigation_v0
from sb3_macb.envs.joint_env import AgentLayout, JointEnv, make_joint_env
from sb3_macb.envs.registration import ENV_IDS, register_envs

register_envs()

__all__ = [
    "ENV_IDS",
    "AgentLayout",
    "JointEnv",
    "communicative_navigation_v0",
    "make_joint_env",
    "register_envs",
    "sparse_spread_v0",
    "two_agent_navigation_v0",
]
