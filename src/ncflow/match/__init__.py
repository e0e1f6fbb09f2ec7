"""The matcher, one pipeline stage per module: prepare (inputs, normalisation, placement) → targets →
pose search → objective / train (with the pose fit, the guard and the progress display) → result.

``Matcher`` and :func:`match` are the entry points. The package itself is callable:
``ncflow.match(source, target, skeleton)`` runs :func:`ncflow.match.matcher.match`, so the public
function and the package can share the name ``ncflow.match`` (and ``import ncflow.match.placement``
still reaches the submodules).
"""

import sys
import types

from ncflow.match.matcher import Matcher, match
from ncflow.match.result import MatchResult
from ncflow.match.train import TrainingError

__all__ = ["MatchResult", "Matcher", "TrainingError", "match"]


class _CallablePackage(types.ModuleType):
    def __call__(self, *args, **kwargs):
        return match(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
