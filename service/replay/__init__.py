"""The offline path: logs through the live monitor code into a new log and the health store
(``core``), its inputs and identities (``input``), batches on workers (``cluster``: ``--jobs``,
``--cluster``) and the fleet simulator that drives it (``fleetsim``). May import every layer
below it, never cli.

``service.replay`` keeps the names it had as a module (``replay``, ``replay_many``, ...).
"""

from service.replay.core import *  # noqa: F403
from service.replay.core import __all__  # noqa: F401
