from sb3_macb.exploration.count_table import CountTable
from sb3_macb.exploration.macb import MACB, SimHash

__all__ = ["MACB", "CountTable", "SimHash"]
