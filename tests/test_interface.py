"""The documented interface (client_protocol/interface.py) matches the types and the running server."""

from __future__ import annotations

import pytest

from client_protocol.interface import ENDPOINTS
from client_protocol.registry import TypeRegistry
from support import RawClient

REGISTRY = TypeRegistry()


@pytest.mark.parametrize("endpoint", ENDPOINTS, ids=lambda e: e.name)
def test_every_example_fits_its_type(endpoint):
    if endpoint.direction == "call":
        request, _ = REGISTRY.service_parts(endpoint.type)
        REGISTRY.validate(request, endpoint.example)
    else:
        REGISTRY.validate(endpoint.type, endpoint.example)


def test_the_server_offers_each_endpoint_with_its_type(sim_server):
    bus = sim_server.server.bus
    offered = sim_server.call(lambda: ({n: t.type for n, t in bus.topics.items()},
                                       {n: s.type for n, s in bus.services.items()}))
    topics, services = offered
    for e in ENDPOINTS:
        table = services if e.direction == "call" else topics
        assert table.get(e.name) == e.type, f"{e.name}: documented {e.type}, server has {table.get(e.name)}"


def test_example_frames_are_accepted_over_the_wire(sim_server):
    """Each documented client frame, sent as is, gets no error (services may refuse by state, not by form)."""
    client = RawClient(sim_server.url)
    try:
        for e in ENDPOINTS:
            if e.direction != "publish" or e.name.startswith("/qt_robot/"):
                continue  # robot commands would move the shared stand-in; their types are checked above
            client.send(e.example_frame())
        assert client.silent(0.5)
        client.alive()
    finally:
        client.close()
