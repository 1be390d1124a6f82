"""Wire messages, key expressions, the JSON codec and its bounds: the layer that
``sim_sources/`` and ``stream/`` both import from below (depends on ``kinematics.errors``).

The messages and their checks live in :mod:`wire.messages`, encoding, decoding, model framing
and drop counting in :mod:`wire.codec`; their ``__all__`` together is the package's API.
"""

from wire import codec, messages
from wire.codec import *  # noqa: F403
from wire.messages import *  # noqa: F403

__all__ = [*messages.__all__, *codec.__all__]
