"""Neural ODE flow: Flow-Net fields, the fixed-grid integrator with dense output (DESIGN.md "Flow"),
and the GSO-Net local-rotation network (DESIGN.md "Soft tissue")."""

from .fields import DivFreeFlowField, FlowField, divergence, make_flow_field
from .gso import GSONet, rotation_angle, rotation_from_6d
from .integrate import flow_points, hermite, integrate, time_grid

__all__ = [
    "DivFreeFlowField",
    "FlowField",
    "GSONet",
    "divergence",
    "flow_points",
    "hermite",
    "integrate",
    "make_flow_field",
    "rotation_angle",
    "rotation_from_6d",
    "time_grid",
]
