from sb3_macb.envs.joint_env import AgentLayout, JointEnv, make_joint_env

__all__ = ["AgentLayout", "JointEnv", "make_joint_env"]
