from sb3_macb.common.grouped_mlp import GroupedMLP, onednn_available

__all__ = ["GroupedMLP", "onednn_available"]
