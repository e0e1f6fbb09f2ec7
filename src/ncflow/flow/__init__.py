"""Neural ODE flow: Flow-Net fields, the integrator, the GSO-Net and the skeleton-driven field.

The Flow-Net fields and the fixed-grid integrator with dense output (DESIGN.md "Flow"), the GSO-Net
local-rotation network (DESIGN.md "Soft tissue") and the skeleton-driven field
(:class:`SkinnedField`).
"""

from ncflow.flow.bone_weights import skinning_weights
from ncflow.flow.fields import DivFreeFlowField, FlowField, divergence, make_flow_field
from ncflow.flow.gso import GSONet, rotation_from_6d
from ncflow.flow.integrate import flow_points, hermite, integrate, time_grid
from ncflow.flow.islands import surface_skin
from ncflow.flow.skinning import SkinnedField, bone_velocities

__all__ = [
    "DivFreeFlowField",
    "FlowField",
    "GSONet",
    "SkinnedField",
    "bone_velocities",
    "divergence",
    "flow_points",
    "hermite",
    "integrate",
    "make_flow_field",
    "rotation_from_6d",
    "skinning_weights",
    "surface_skin",
    "time_grid",
]
