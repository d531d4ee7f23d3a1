"""The one exception every layer may raise for a request it refuses, so that the robot needs no bus to refuse."""


class Refusal(Exception):
    """A request refused; its message is shown to the client as it is (a service response, a status op)."""
