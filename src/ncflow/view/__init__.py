"""The offline web page of a result (:func:`write_view`): source, flowed source and target side by side,
the animation, the skeleton and the geodesic-error map, in one file a browser opens without a server
(the page script, three.js bundled by ``viewer/build.sh``, is in ``assets/``).
"""

from ncflow.view.page import write_view

__all__ = ["write_view"]
