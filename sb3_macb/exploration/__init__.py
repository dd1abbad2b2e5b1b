from sb3_macb.exploration.count_min import CountMinSketch
from sb3_macb.exploration.count_table import CountTable
from sb3_macb.exploration.estimators import make_exploration
from sb3_macb.exploration.macb import MACB, SimHash
from sb3_macb.exploration.normalize import BonusNormalizer
from sb3_macb.exploration.rnd import RND

__all__ = ["MACB", "RND", "BonusNormalizer", "CountMinSketch", "CountTable", "SimHash", "make_exploration"]
