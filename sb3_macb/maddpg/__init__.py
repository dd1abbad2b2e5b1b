from sb3_macb.maddpg.maddpg import MADDPG
from sb3_macb.maddpg.pack import Pack
from sb3_macb.maddpg.policies import MADDPGPolicy, MlpPolicy

__all__ = ["MADDPG", "MADDPGPolicy", "MlpPolicy", "Pack"]
