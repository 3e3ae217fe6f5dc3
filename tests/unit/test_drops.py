"""DropCounter: counts per reason, logs at most once per reason per interval."""

from __future__ import annotations

import logging

import pytest
from bipedtele.link.drops import DropCounter


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_counts_per_reason_and_total() -> None:
    d = DropCounter("rx", clock=FakeClock())
    for _ in range(3):
        d.drop("stale")
    d.drop("not_msgpack", "TypeError")
    assert d.counts() == {"stale": 3, "not_msgpack": 1}
    assert d.total == 4
    c = d.counts()
    c["stale"] = 0
    assert d.counts()["stale"] == 3  # a copy


def test_logs_once_per_reason_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    clock = FakeClock()
    d = DropCounter("rx", log_interval_s=5.0, clock=clock)
    with caplog.at_level(logging.WARNING, logger="bipedtele.link.drops"):
        for _ in range(10):
            d.drop("stale")
        d.drop("bad_field")
        assert len(caplog.records) == 2
        clock.t = 4.9
        d.drop("stale")
        assert len(caplog.records) == 2
        clock.t = 5.0
        d.drop("stale", "seq=3")
    assert len(caplog.records) == 3
    last = caplog.records[-1].getMessage()
    # 9 dropped silently + 1 at t=4.9 + this one
    assert "dropped 11 message(s): stale" in last and "seq=3" in last
    assert d.counts() == {"stale": 12, "bad_field": 1}


def test_negative_interval_rejected() -> None:
    with pytest.raises(ValueError):
        DropCounter("x", log_interval_s=-1)


def test_unauthentic_messages_amid_genuine_ones_read_as_an_attack_not_a_key_mismatch(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = FakeClock()
    d = DropCounter("follower", log_interval_s=0.0, clock=clock)
    key_line = "bipedtele/nao1/cmd: MAC mismatch: the two sides hold different message keys (wrong tag)"
    with caplog.at_level(logging.WARNING, logger="bipedtele.link.drops"):
        d.drop("bad_mac", key_line)  # nothing genuine yet: the keys may well differ
        d.authentic()
        clock.t = 1.0
        for reason in ("bad_mac", "no_mac", "no_session", "stale"):
            d.drop(reason, key_line)
        clock.t = 1.0 + 5.0  # nothing genuine for the window: a mismatch again
        d.drop("bad_mac", key_line)
    lines = [r.getMessage() for r in caplog.records]
    assert "different message keys" in lines[0] and "under attack" not in lines[0]
    for line in lines[1:4]:
        assert "under attack? bipedtele/nao1/cmd" in line and "different message keys" not in line, line
        assert "not a key mismatch" in line and "ACL" not in line
    assert "under attack" not in lines[4]  # stale: not an authentication failure
    assert "different message keys" in lines[5] and "under attack" not in lines[5]
