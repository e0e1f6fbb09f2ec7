"""The matcher as plain steps: prepare → programs → place → targets → train → result (one module each;
:mod:`ncflow.matcher.steps` runs them). :func:`match` is the entry point (``ncflow.match``).
"""

from ncflow.matcher.result import MatchResult
from ncflow.matcher.steps import Matcher, match
from ncflow.matcher.train import TrainingError

__all__ = ["MatchResult", "Matcher", "TrainingError", "match"]
