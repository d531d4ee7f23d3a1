"""rosapi's services, as roslibpy, roslibjs and ROS# call them, answered from the bus, plus a parameter server."""

from __future__ import annotations

import json
from typing import Any

from client_protocol.registry import normalize_type_name

from .bus import SERVER_NODE, Bus, BusError

ROSAPI_NODE = "/rosapi"


class RosApi:
    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.params: dict[str, str] = {}  # name -> JSON text, as rosapi stores them

    def start(self) -> None:
        bus = self.bus
        bus.declare_topic("/rosout", "rosgraph_msgs/Log", persistent=True)
        r = bus.registry
        handlers = {
            "topics": ("rosapi/Topics", self._topics),
            "topic_type": ("rosapi/TopicType", self._topic_type),
            "topics_for_type": ("rosapi/TopicsForType", self._topics_for_type),
            "services": ("rosapi/Services", self._services),
            "service_type": ("rosapi/ServiceType", self._service_type),
            "services_for_type": ("rosapi/ServicesForType", self._services_for_type),
            "nodes": ("rosapi/Nodes", self._nodes),
            "node_details": ("rosapi/NodeDetails", self._node_details),
            "get_time": ("rosapi/GetTime", lambda _req: {"time": r.now()}),
            "message_details": ("rosapi/MessageDetails", lambda req: self._details(req.type, None)),
            "service_request_details": ("rosapi/ServiceRequestDetails", lambda req: self._details(req.type, 0)),
            "service_response_details": ("rosapi/ServiceResponseDetails", lambda req: self._details(req.type, 1)),
            "publishers": ("rosapi/Publishers", lambda req: {"publishers": self._owners(req.topic, True)}),
            "subscribers": ("rosapi/Subscribers", lambda req: {"subscribers": self._owners(req.topic, False)}),
            "get_param": ("rosapi/GetParam", self._get_param),
            "set_param": ("rosapi/SetParam", self._set_param),
            "has_param": ("rosapi/HasParam", lambda req: {"exists": req.name in self.params}),
            "delete_param": ("rosapi/DeleteParam", self._delete_param),
            "get_param_names": ("rosapi/GetParamNames", lambda _req: {"names": sorted(self.params)}),
            "action_servers": ("rosapi/GetActionServers", lambda _req: {"action_servers": sorted(bus.actions)}),
        }
        for name, (type_name, handler) in handlers.items():
            bus.advertise_service(ROSAPI_NODE, f"/rosapi/{name}", type_name, self._wrap(handler))

    async def stop(self) -> None:
        """Nothing runs in the background; the services go with the bus."""

    @staticmethod
    def _wrap(handler):
        async def provider(request: Any, _timeout: float) -> Any:
            return handler(request)
        return provider

    def _topics(self, _req: Any) -> dict[str, Any]:
        names = sorted(self.bus.topics)
        return {"topics": names, "types": [self.bus.topics[n].type for n in names]}

    def _topic_type(self, req: Any) -> dict[str, Any]:
        topic = self.bus.topics.get(req.topic)
        return {"type": topic.type if topic else ""}

    def _topics_for_type(self, req: Any) -> dict[str, Any]:
        wanted = normalize_type_name(req.type)
        return {"topics": sorted(n for n, t in self.bus.topics.items() if t.type == wanted)}

    def _services(self, _req: Any) -> dict[str, Any]:
        return {"services": sorted(self.bus.services)}

    def _service_type(self, req: Any) -> dict[str, Any]:
        service = self.bus.services.get(req.service)
        return {"type": service.type if service else ""}

    def _services_for_type(self, req: Any) -> dict[str, Any]:
        wanted = normalize_type_name(req.type)
        return {"services": sorted(n for n, s in self.bus.services.items() if s.type == wanted)}

    def _all_owners(self) -> set[str]:
        owners = {SERVER_NODE, ROSAPI_NODE}
        for topic in self.bus.topics.values():
            owners.update(topic.publishers)
            owners.update(owner for owner, _ in topic.subscribers.values())
        owners.update(s.owner for s in self.bus.services.values())
        return owners

    def _nodes(self, _req: Any) -> dict[str, Any]:
        return {"nodes": sorted(self._all_owners())}

    def _node_details(self, req: Any) -> dict[str, Any]:
        topics = self.bus.topics.values()
        return {
            "subscribing": sorted(t.name for t in topics if any(o == req.node for o, _ in t.subscribers.values())),
            "publishing": sorted(t.name for t in topics if req.node in t.publishers),
            "services": sorted(n for n, s in self.bus.services.items() if s.owner == req.node),
        }

    def _owners(self, topic_name: str, publishers: bool) -> list[str]:
        topic = self.bus.topics.get(topic_name)
        if topic is None:
            return []
        return sorted(topic.publishers) if publishers else sorted({o for o, _ in topic.subscribers.values()})

    def _details(self, type_name: str, service_part: int | None) -> dict[str, Any]:
        registry = self.bus.registry
        if service_part is None:
            if not registry.is_known_message(type_name):
                raise BusError(f"message type {type_name!r} is not known to this server")
            return {"typedefs": registry.typedefs(type_name)}
        if not registry.is_known_service(type_name):
            raise BusError(f"service type {type_name!r} is not known to this server")
        return {"typedefs": registry.typedefs(registry.service_parts(type_name)[service_part])}

    def _get_param(self, req: Any) -> dict[str, Any]:
        if req.name in self.params:
            return {"value": self.params[req.name]}
        return {"value": req.default if req.default else "null"}

    def _set_param(self, req: Any) -> dict[str, Any]:
        try:
            json.loads(req.value)
        except json.JSONDecodeError as exc:
            raise BusError(f"parameter {req.name}: the value must be JSON text (e.g. \"5\" or \"\\\"text\\\"\"), "
                           f"but it is not: {exc.msg}") from None
        self.params[req.name] = req.value
        return {}

    def _delete_param(self, req: Any) -> dict[str, Any]:
        if self.params.pop(req.name, None) is None:
            raise BusError(f"parameter {req.name} does not exist")
        return {}

