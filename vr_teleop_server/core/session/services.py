"""The service ops: calls from the client, services the client provides, and their answers."""

from __future__ import annotations

import asyncio
import itertools
import logging
from typing import Any

from client_protocol import ops

from ..bus import Bus, BusError, CallFailed
from ..settings import CoreSettings
from .protocol import ProtocolError, json_value

log = logging.getLogger(__name__)


class ServiceOps:
    """Mixed into Session: its handlers of the service ops."""

    name: str
    bus: Bus
    settings: CoreSettings
    services: set[str]
    _tasks: set[asyncio.Task[Any]]
    _calls_to_me: dict[str, asyncio.Future[Any]]
    _ids: itertools.count

    def _op_call_service(self, op: ops.CallService) -> None:
        if len(self._tasks) >= self.settings.max_pending_calls:
            raise ProtocolError(f"this client already has {len(self._tasks)} calls in progress; wait for answers")
        self._spawn(self._call_service(op))

    async def _call_service(self, op: ops.CallService) -> None:
        timeout = op.timeout or self.settings.service_timeout
        try:
            response = await self.bus.call_service(op.service, op.args, timeout, caller=self.name)
        except BusError as exc:
            self.status("error", f"call_service: {exc}", op.id)
            self._reply(self._with_id({"op": "service_response", "service": op.service, "values": str(exc),
                                       "result": False}, op.id), op.compression, op.fragment_size, op.id)
            return
        service = self.bus.services.get(op.service)
        redacted = None
        if service is not None and service.confidential:  # the recording keeps that it was answered, not what
            redacted = self._dumps(self._with_id({"op": "service_response", "service": op.service,
                                                  "values": "***", "result": True}, op.id))
        self._reply(self._with_id({"op": "service_response", "service": op.service,
                                   "values": json_value(response), "result": True}, op.id),
                    op.compression, op.fragment_size, op.id, redacted=redacted)

    def _op_advertise_service(self, op: ops.AdvertiseService) -> None:
        self.bus.advertise_service(self.name, op.service, op.type,
                                   lambda request, timeout, name=op.service: self._serve_call(name, request))
        self.services.add(op.service)

    def _op_unadvertise_service(self, op: ops.UnadvertiseService) -> None:
        if op.service not in self.services:
            raise ProtocolError(f"service {op.service} is not advertised by this client", "warning")
        self.services.discard(op.service)
        self.bus.unadvertise_service(self.name, op.service)
        for call_id, future in list(self._calls_to_me.items()):
            if call_id.startswith(f"service_request:{op.service}:") and not future.done():
                future.set_exception(CallFailed(f"service {op.service} was withdrawn by its provider"))

    async def _serve_call(self, service: str, request: Any) -> Any:
        """Forwards a call to this client, which provides the service, and waits for its service_response."""
        call_id = f"service_request:{service}:{next(self._ids)}"
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._calls_to_me[call_id] = future
        self._send({"op": "call_service", "id": call_id, "service": service, "args": json_value(request)})
        try:
            return await future
        finally:
            self._calls_to_me.pop(call_id, None)

    def _op_service_response(self, op: ops.ServiceResponse) -> None:
        future = self._calls_to_me.get(str(op.id)) if op.id is not None else None
        if future is None or future.done():
            raise ProtocolError(f"no call with id {op.id!r} is waiting for an answer (it may have timed out)",
                                "warning")
        if not op.result:
            # rosbridge's rule: the values go to the caller whatever `result` says (filled with defaults below);
            # only values that cannot be a response at all make the call fail
            log.warning("%s answered %s with result false: %.200s", self.name, op.service, op.values)
            if not isinstance(op.values, dict):
                future.set_exception(CallFailed(f"service {op.service} reported failure: {op.values}"))
                return
        service = self.bus.services.get(op.service)
        try:
            values = self.bus.validate_response(service, op.values) if service is not None else op.values
        except BusError as exc:
            future.set_exception(exc)
            raise
        future.set_result(values)
