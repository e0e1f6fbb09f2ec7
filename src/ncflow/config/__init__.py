"""Matcher configuration: the settings tree (:mod:`~ncflow.config.settings`, each field with its range,
choices and message), the presets, files and overrides, the one validator and every ``Config → Config``
transform.
"""

from ncflow.config.checks import validate_config, walk
from ncflow.config.files import apply_overrides, load_config
from ncflow.config.presets import PRESETS, preset
from ncflow.config.quoting import QUOTE_LIMIT, quote
from ncflow.config.settings import (
    METRICS,
    RESULT_NEUTRAL,
    SEED_LIMIT,
    Config,
    ConstraintConfig,
    FlowConfig,
    PhaseConfig,
    RepairConfig,
    SamplingConfig,
    TissueConfig,
    WeightsConfig,
)
from ncflow.config.transforms import (
    ablation_config,
    config_to_dict,
    result_config,
    scale_steps,
    with_metric,
    with_options,
)

__all__ = [
    "METRICS",
    "PRESETS",
    "QUOTE_LIMIT",
    "RESULT_NEUTRAL",
    "SEED_LIMIT",
    "Config",
    "ConstraintConfig",
    "FlowConfig",
    "PhaseConfig",
    "RepairConfig",
    "SamplingConfig",
    "TissueConfig",
    "WeightsConfig",
    "ablation_config",
    "apply_overrides",
    "config_to_dict",
    "load_config",
    "preset",
    "result_config",
    "quote",
    "scale_steps",
    "validate_config",
    "walk",
    "with_metric",
    "with_options",
]
