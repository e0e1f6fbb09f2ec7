"""The smallest networks and samples a match runs with: the settings the matcher's tests share."""

TINY = [
    "flow.width=8",
    "flow.depth=1",
    "flow.gso_width=4",
    "flow.gso_depth=1",
    "flow.n_times=3",
    "sampling.bone_samples=5",
    "sampling.tissue_samples=16",
    "sampling.surface_edges=64",
    "frames=3",
]
