from sb3_macb.matd3.matd3 import MATD3

__all__ = ["MATD3"]
