"""The one log format of every servowatch process lives in ``service.log.setup`` (the replay
workers and the MCAP log process use it too); the CLI's name for it."""

from service.log.setup import *  # noqa: F403
from service.log.setup import __all__  # noqa: F401
