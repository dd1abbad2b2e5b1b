"""The exploration study's candidate tasks: a name, the gym id and its ``env_kwargs`` (all vectorized)."""

SPREAD = "sb3_macb/SparseSpread-v0"
NAV = "sb3_macb/TwoAgentNavigation-v0"
COMM = "sb3_macb/CommunicativeNavigation-v0"

CANDIDATES: dict[str, tuple[str, dict]] = {
    "spread3": (SPREAD, {"n_agents": 3}),
    "spread6": (SPREAD, {"n_agents": 6}),
    "nav-success": (NAV, {"reward": "success"}),
    "comm6-wide": (COMM, {"n_landmarks": 6, "half_width": 2.0, "max_cycles": 40}),
}
