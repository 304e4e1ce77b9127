"""Which sample protocol a build follows: every protocol the pipeline knows, by name.

The stages never import a protocol's module: the pipeline hands its tasks the `SampleProtocol`
of the build's `config.protocol` (`windows.SampleProtocol`).
"""

from __future__ import annotations

from ngsim_graphs.config import BuildConfig
from ngsim_graphs.cslstm import CS_LSTM
from ngsim_graphs.schema import Protocol
from ngsim_graphs.windows import AIGEM, SampleProtocol

PROTOCOLS: dict[Protocol, SampleProtocol] = {Protocol.AIGEM: AIGEM, Protocol.CS_LSTM: CS_LSTM}


def check_protocol_locations(config: BuildConfig) -> None:
    """ValueError where the build's locations are not all among those its protocol reads."""
    taken = PROTOCOLS[config.protocol].locations
    if taken is None:
        return
    names, why = taken
    others = sorted(set(config.locations) - set(names))
    if others:
        raise ValueError(
            f"the {config.protocol.value} protocol reads {' and '.join(names)} only ({why}), "
            f"not {', '.join(others)}"
        )
