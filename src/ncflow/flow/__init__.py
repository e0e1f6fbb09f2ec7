"""Neural ODE flow: Flow-Net fields and the fixed-grid integrator with dense output (DESIGN.md "Flow")."""

from .fields import DivFreeFlowField, FlowField, divergence, make_flow_field
from .integrate import flow_points, hermite, integrate, time_grid

__all__ = [
    "DivFreeFlowField",
    "FlowField",
    "divergence",
    "flow_points",
    "hermite",
    "integrate",
    "make_flow_field",
    "time_grid",
]
