"""
The exploration study's candidate tasks: the gym id, its ``env_kwargs`` and the episode length (all vectorized by
:func:`sb3_macb.envs.vec_tasks.make_task_vec_env`), and each task's budget of training steps per run.
"""

SPREAD = "sb3_macb/SparseSpread-v0"
NAV = "sb3_macb/TwoAgentNavigation-v0"
COMM = "sb3_macb/CommunicativeNavigation-v0"

CANDIDATES: dict[str, tuple[str, dict]] = {
    "spread3": (SPREAD, {"n_agents": 3}),
    "spread6": (SPREAD, {"n_agents": 6}),
    "nav-success": (NAV, {"reward": "success"}),
    "comm6-wide": (COMM, {"n_landmarks": 6, "half_width": 2.0, "max_cycles": 40}),
}

EPISODE_STEPS = {"spread3": 25, "spread6": 25, "nav-success": 20, "comm6-wide": 40}

# Training steps per run (the pilots' and the study's), fixed in README.md before any pilot ran: 4,000 episodes,
# Sparse Spread with 6 agents 2,000 (its update costs about 3.5 times the others' per episode)
BUDGET = {"spread3": 100_000, "spread6": 50_000, "nav-success": 80_000, "comm6-wide": 160_000}
