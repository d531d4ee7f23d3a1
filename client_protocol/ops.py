"""The rosbridge v2 operations, as pydantic models: what a client may send and what the server sends back.

Known fields are strictly typed; fields a model does not name are ignored, as rosbridge ignores them, because
clients add their own (roslibjs sends `latch` and `queue_size`, ROS# sends `type` on calls).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, StrictStr, TypeAdapter

Id = Union[StrictStr, StrictInt]
StatusLevel = Literal["info", "warning", "error", "none"]
TopicCompression = Literal["none", "png", "cbor", "cbor-raw"]
ResponseCompression = Literal["none", "png"]
Args = Union[list[Any], dict[str, Any], None]
Name = Annotated[StrictStr, Field(min_length=1)]


class Op(BaseModel):
    model_config = ConfigDict(strict=True, extra="ignore")
    id: Id | None = None


# ---- topics ---------------------------------------------------------------------------------------------------
class Advertise(Op):
    """Declares that this client will publish `topic` with `type`."""
    op: Literal["advertise"]
    topic: Name
    type: Name
    latch: StrictBool = False
    queue_size: Annotated[StrictInt, Field(ge=0)] = 100


class Unadvertise(Op):
    op: Literal["unadvertise"]
    topic: Name


class Publish(Op):
    """A message on a topic: client to server, and server to each subscribed client (one frame per topic)."""
    op: Literal["publish"]
    topic: Name
    msg: Any = None
    latch: StrictBool = False


class Subscribe(Op):
    """Asks for a topic's messages. `throttle_rate` is the least time between two messages, in ms;
    `queue_length` how many to keep while throttled or while the client reads slowly (the oldest goes first)."""
    op: Literal["subscribe"]
    topic: Name
    type: StrictStr | None = None
    throttle_rate: Annotated[StrictInt, Field(ge=0)] = 0
    queue_length: Annotated[StrictInt, Field(ge=0)] = 0
    fragment_size: Annotated[StrictInt, Field(gt=0)] | None = None
    compression: TopicCompression = "none"


class Unsubscribe(Op):
    """Without `id`, ends every subscription this client holds on `topic`; with it, only that one."""
    op: Literal["unsubscribe"]
    topic: Name


# ---- services -------------------------------------------------------------------------------------------------
class CallService(Op):
    """Calls a service; `args` as an object, or as a list in the request's field order. `timeout` in seconds."""
    op: Literal["call_service"]
    service: Name
    args: Args = None
    fragment_size: Annotated[StrictInt, Field(gt=0)] | None = None
    compression: ResponseCompression = "none"
    timeout: Annotated[float, Field(gt=0)] | None = None


class AdvertiseService(Op):
    op: Literal["advertise_service"]
    service: Name
    type: Name


class UnadvertiseService(Op):
    op: Literal["unadvertise_service"]
    service: Name


class ServiceResponse(Op):
    """The answer to a call: from the server to the caller, or from a providing client to the server."""
    op: Literal["service_response"]
    service: Name
    values: Any = None
    result: StrictBool = True


# ---- actions --------------------------------------------------------------------------------------------------
class AdvertiseAction(Op):
    op: Literal["advertise_action"]
    action: Name
    type: Name


class UnadvertiseAction(Op):
    op: Literal["unadvertise_action"]
    action: Name


class SendActionGoal(Op):
    op: Literal["send_action_goal"]
    action: Name
    action_type: Name
    args: Args = None
    feedback: StrictBool = False
    fragment_size: Annotated[StrictInt, Field(gt=0)] | None = None
    compression: ResponseCompression = "none"


class CancelActionGoal(Op):
    op: Literal["cancel_action_goal"]
    id: Id
    action: Name


class ActionFeedback(Op):
    op: Literal["action_feedback"]
    id: Id
    action: Name
    values: Any = None


class ActionResult(Op):
    """`status` follows action_msgs/GoalStatus: 4 succeeded, 5 canceled, 6 aborted."""
    op: Literal["action_result"]
    id: Id
    action: Name
    values: Any = None
    status: Annotated[StrictInt, Field(ge=0, le=6)]
    result: StrictBool


# ---- encodings and logging ------------------------------------------------------------------------------------
class Fragment(Op):
    """One piece of a message's JSON text; the pieces of one message share `id` and are joined in `num` order."""
    op: Literal["fragment"]
    id: Id
    data: StrictStr
    num: Annotated[StrictInt, Field(ge=0)]
    total: Annotated[StrictInt, Field(ge=1)]


class Png(Op):
    """Server to client: a message's JSON text packed into the pixels of a PNG image, base64-encoded."""
    op: Literal["png"]
    data: StrictStr
    num: Annotated[StrictInt, Field(ge=0)] | None = None
    total: Annotated[StrictInt, Field(ge=1)] | None = None


class SetLevel(Op):
    """The least level of `status` messages this client wants (default: error)."""
    op: Literal["set_level"]
    level: StatusLevel


class Status(Op):
    """A report from the server about an operation (named by `id`), or a client's log line to the server."""
    op: Literal["status"]
    level: StatusLevel
    msg: StrictStr


class Auth(Op):
    """Authenticates the connection (rosbridge's auth op). This server carries a role's token in `mac`; the other
    fields of rosbridge's MAC scheme (client, dest, rand, t, level, end) are accepted and ignored."""
    op: Literal["auth"]
    mac: Name


CLIENT_OPS: tuple[type[Op], ...] = (
    Advertise, Unadvertise, Publish, Subscribe, Unsubscribe, CallService, AdvertiseService, UnadvertiseService,
    ServiceResponse, AdvertiseAction, UnadvertiseAction, SendActionGoal, CancelActionGoal, ActionFeedback,
    ActionResult, Fragment, SetLevel, Status, Auth,
)
SERVER_OPS: tuple[type[Op], ...] = (
    Publish, ServiceResponse, CallService, Status, Fragment, Png, SendActionGoal, CancelActionGoal,
    ActionFeedback, ActionResult,
)


def op_name(model: type[Op]) -> str:
    return model.model_fields["op"].annotation.__args__[0]  # type: ignore[union-attr]


CLIENT_OP_MODELS: dict[str, type[Op]] = {op_name(m): m for m in CLIENT_OPS}
ClientOp = Annotated[Union[CLIENT_OPS], Field(discriminator="op")]  # type: ignore[valid-type]
CLIENT_OP_ADAPTER: TypeAdapter[Any] = TypeAdapter(ClientOp)
