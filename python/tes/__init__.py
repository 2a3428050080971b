"""TES from Python: mDAGL, the paper's agents and its worlds, over the same Rust code as the
``tes`` controller (Nguyen et al., *Scalable transfer learning in heterogeneous, dynamic
environments*, AIJ 2017).

* :class:`Mdagl` — online sparse multinomial logistic regression with group lasso, as a
  scikit-learn classifier (λ and α raced by default, as ``tes fit --lambda auto``).
* :mod:`tes.agents` — ``LoreRL``, ``TES``, ``LWT``, ``FEpsG`` on any environment that
  declares its structure (:mod:`tes.structure`); :mod:`tes.adapters` has ready structures.
* :func:`run` — an agent's episodes on a Gymnasium environment.
* ``tes/GridTask-v0`` and ``tes/Arena-v0`` — the paper's worlds, registered with Gymnasium on
  import (:mod:`tes.envs`).

The distribution is ``tes-transfer``; the import name is ``tes``. Every object is safe to share
between threads, and copies and pickles into one that goes on exactly as the original.

>>> import numpy as np, tes
>>> model = tes.Mdagl(lam=0.05, alpha=1.5)
>>> model.partial_fit(np.eye(4), ["a", "b", "a", "b"], classes=["a", "b"]).n_updates_
4
>>> model.predict(np.eye(4)[:1]).tolist()
['a']
"""

import gymnasium as _gymnasium

from tes import adapters, agents, evaluate, structure
from tes._mdagl import Mdagl
from tes._run import run
from tes._tes import LibraryFileError, __version__

__all__ = [
    "Mdagl",
    "LibraryFileError",
    "adapters",
    "agents",
    "evaluate",
    "run",
    "structure",
    "__version__",
]


def _register() -> None:
    for env_id, entry_point in (
        ("tes/GridTask-v0", "tes.envs:GridTaskEnv"),
        ("tes/Arena-v0", "tes.envs:ArenaEnv"),
    ):
        if env_id not in _gymnasium.registry:
            _gymnasium.register(id=env_id, entry_point=entry_point)


_register()
