"""TES from Python: mDAGL (online sparse multinomial logistic regression with group lasso),
over the same Rust code as the ``tes`` controller and ``tes fit``.

>>> import numpy as np, tes
>>> model = tes.Mdagl(n_features=4, n_classes=2)
>>> model.partial_fit(np.eye(4), np.array([0, 1, 0, 1])).n_updates_
4
"""

from tes._mdagl import Mdagl
from tes._tes import __version__

__all__ = ["Mdagl", "__version__"]
