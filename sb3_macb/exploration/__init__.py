from sb3_macb.exploration.count_min import CountMinSketch
from sb3_macb.exploration.count_table import CountTable
from sb3_macb.exploration.macb import MACB, SimHash
from sb3_macb.exploration.normalize import BonusNormalizer

__all__ = ["MACB", "BonusNormalizer", "CountMinSketch", "CountTable", "SimHash"]
