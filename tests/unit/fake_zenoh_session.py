"""Just enough of a Zenoh session for a receiver's unit tests: its callback is called by hand.

Unit tests only: the integration and e2e tests use real Zenoh sessions.
"""

from __future__ import annotations

from typing import Any

from bipedtele.link.messages import Message, encode

KEY = "bipedtele/nao1/cmd"


class Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    def __init__(self, data: bytes, key: str) -> None:
        self.payload = Payload(data)
        self.key_expr = key


class _Sub:
    def undeclare(self) -> None:
        pass


class FakeSession:
    """A session whose one subscriber's callback :meth:`put` and :meth:`put_bytes` call."""

    def __init__(self) -> None:
        self.callback: Any = None

    def declare_subscriber(self, key: str, callback: Any) -> _Sub:
        self.callback = callback
        return _Sub()

    def put_bytes(self, data: bytes, key: str = KEY) -> None:
        self.callback(_Sample(data, key))

    def put(self, msg: Message, key: str = KEY) -> None:
        self.put_bytes(encode(msg), key)
