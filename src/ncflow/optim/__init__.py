"""Optimisers (cautious AdaBelief / VectorAdam), learning-rate schedules and MDMM constraints
(DESIGN.md "Optimiser", "Constraints (MDMM)")."""

from ncflow.optim.mdmm import (
    clamp_multipliers,
    mdmm_term,
    reverse_gradient,
    soft_constraint_term,
    update_multipliers,
    violation,
)
from ncflow.optim.optimizers import (
    adabelief_cautious,
    cautious,
    is_vector_array,
    scale_by_vector_adam,
    vectoradam_cautious,
)
from ncflow.optim.schedules import piecewise_phases, warmup_constant, warmup_cosine

__all__ = [
    "adabelief_cautious",
    "cautious",
    "clamp_multipliers",
    "is_vector_array",
    "mdmm_term",
    "piecewise_phases",
    "reverse_gradient",
    "scale_by_vector_adam",
    "soft_constraint_term",
    "update_multipliers",
    "vectoradam_cautious",
    "violation",
    "warmup_constant",
    "warmup_cosine",
]
