"""Which sample protocol a build follows: every protocol the pipeline knows, by name.

The stages never import a protocol's module: the pipeline hands its tasks the `SampleProtocol`
of the build's `config.protocol` (`windows.SampleProtocol`).
"""

from __future__ import annotations

from ngsim_graphs.cslstm import CS_LSTM
from ngsim_graphs.schema import Protocol
from ngsim_graphs.windows import AIGEM, SampleProtocol

PROTOCOLS: dict[Protocol, SampleProtocol] = {Protocol.AIGEM: AIGEM, Protocol.CS_LSTM: CS_LSTM}
