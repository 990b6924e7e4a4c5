"""The wire protocol (protocol/SPEC.md), one module per part as in the protocol crate:

- :mod:`.envelope`: MessagePack, binary arrays and the reply envelope (``array.rs``,
  ``codec.rs``, ``messages/envelope.rs``);
- :mod:`.requests`: :class:`EnvSpec` and the request builders (``messages/requests.rs``);
- :mod:`.replies`: the one reply decoder, numpy views of the payload (``messages/replies.rs``);
- :mod:`.errors`: the exceptions, one per server error code (``error.rs``).

Nothing here opens a connection: :mod:`sharedspace.client` sends these bytes.
"""

from .envelope import ARRAY_DTYPES, PADDING_ID, PROTOCOL_VERSION, decode, encode
from .errors import ProtocolError, ServerError, SharedspaceError
from .replies import decode_result
from .requests import ComposedScenes, EnvSpec, SyntheticScenes, VariationSpec

__all__ = [
    "ARRAY_DTYPES",
    "PADDING_ID",
    "PROTOCOL_VERSION",
    "EnvSpec",
    "ProtocolError",
    "ServerError",
    "SharedspaceError",
    "SyntheticScenes",
    "ComposedScenes",
    "VariationSpec",
    "decode",
    "decode_result",
    "encode",
]
