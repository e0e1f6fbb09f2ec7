"""Optimisers (cautious AdaBelief / VectorAdam), learning-rate schedules and MDMM constraints
(DESIGN.md "Optimiser", "Constraints (MDMM)").
"""

from ncflow.optim.mdmm import (
    Multipliers,
    ascend_multipliers,
    init_multipliers,
    mdmm_term,
    multiplier_ceiling,
    multiplier_rate,
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
from ncflow.optim.schedules import warmup_constant, warmup_cosine

__all__ = [
    "Multipliers",
    "init_multipliers",
    "update_multipliers",
    "adabelief_cautious",
    "ascend_multipliers",
    "multiplier_ceiling",
    "multiplier_rate",
    "cautious",
    "is_vector_array",
    "mdmm_term",
    "scale_by_vector_adam",
    "soft_constraint_term",
    "vectoradam_cautious",
    "violation",
    "warmup_constant",
    "warmup_cosine",
]
