"""The zoo: rl_zoo3 with MADDPG registered, grid sweeps over Optuna storages, and the paper's plots."""
