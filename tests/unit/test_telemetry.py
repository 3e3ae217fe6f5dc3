"""The typed leader sample: its JSON Schema (units), the recorded channel, reading older
recordings back, the cockpit's JSON, and the leader loop producing it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
from bipedtele.leader.cockpit import SAMPLE_KEYS
from bipedtele.leader.cockpit.server import _sample_json
from bipedtele.recording.format import read_records
from bipedtele.recording.recorder import Recorder
from bipedtele.recording.schemas import LEADER_STATE, LEADER_STATE_FIELDS, leader_state_schema
from bipedtele.telemetry import LeaderSample, sample_from_map, sample_to_json
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

pytestmark = pytest.mark.timeout(60)

T = 1_790_000_000.0
FIELDS = msgspec.structs.fields(LeaderSample)


def full_sample(t: float = T) -> LeaderSample:
    """Every field set, to a value of its type."""
    values: dict[str, object] = {}
    for i, f in enumerate(FIELDS):
        info = msgspec.inspect.type_info(f.type)
        info = info.type if isinstance(info, msgspec.inspect.Metadata) else info
        kinds = info.types if isinstance(info, msgspec.inspect.UnionType) else (info,)
        names = {type(k).__name__ for k in kinds}
        if "FloatType" in names:
            values[f.name] = 0.5 * i - 3.0
        elif "IntType" in names:
            values[f.name] = i
        elif "BoolType" in names:
            values[f.name] = True
        else:
            values[f.name] = "walking"
    values["t"] = t
    return msgspec.convert(values, LeaderSample)


def test_the_schema_is_the_struct_with_a_description_for_every_field() -> None:
    assert list(LEADER_STATE_FIELDS) == [f.name for f in FIELDS]
    for name, prop in LEADER_STATE_FIELDS.items():
        assert prop.get("description"), name
        assert "anyOf" not in prop and "default" not in prop, name
    assert LEADER_STATE_FIELDS["t"]["type"] == "number"  # the one required field
    assert LEADER_STATE_FIELDS["h1_ms"]["type"] == ["number", "null"]
    assert "[ms]" in LEADER_STATE_FIELDS["h1_ms"]["description"]
    assert LEADER_STATE_FIELDS["seq"]["type"] == ["integer", "null"]
    assert LEADER_STATE_FIELDS["enable"]["type"] == ["boolean", "null"]
    assert LEADER_STATE_FIELDS["link"]["type"] == ["string", "null"]
    schema = leader_state_schema()
    assert schema["title"] == LEADER_STATE and schema["required"] == ["t"]
    Draft202012Validator.check_schema(schema)


def test_a_recorded_sample_validates_and_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    full = full_sample()
    sparse = LeaderSample(t=T + 1, seq=2, gain=math.nan, force_v=math.inf, enable=False, h2_ms=np.float64(5.0))  # type: ignore[arg-type]
    with Recorder(path) as rec:
        assert rec.write("leader/state", full, T)
        assert rec.write("leader/state", sparse, T + 1)
        sparse.seq = 99  # the recorder took a copy
    with open(path, "rb") as f:
        reader = make_reader(f)
        messages = list(reader.iter_messages())
    assert {s.name for s, _, _ in messages} == {LEADER_STATE}
    validator = Draft202012Validator(json.loads(messages[0][0].data))
    for _, _, m in messages:
        data = json.loads(m.data, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
        assert not list(validator.iter_errors(data))
    got = [sample_from_map(r.data) for r in read_records(path)]
    assert got[0] == full
    # Non-finite numbers come back as None; unset fields are not written and come back None.
    assert got[1] == LeaderSample(t=T + 1, seq=2, enable=False, h2_ms=5.0)
    assert set(json.loads(messages[1][2].data)) == {"t", "seq", "gain", "force_v", "enable", "h2_ms"}
    # A bad type fails validation against the schema (the schema carries the types).
    assert not validator.is_valid({"t": T, "h1_ms": "slow"})


def test_older_recordings_decode_with_none_for_missing_keys() -> None:
    old = {"t": T, "h1_ms": 120, "h2_ms": 80.5, "falls": 1, "aux_extra": [1, 2]}  # int for a float
    got = sample_from_map(old)
    assert got is not None
    assert (got.t, got.h1_ms, got.h2_ms, got.falls) == (T, 120.0, 80.5, 1)
    assert got.seq is None and got.pose_x is None and got.follower_text is None
    assert sample_from_map({"h1_ms": 1.0}) is None  # no time: not a sample
    assert sample_from_map({"t": T, "h1_ms": "slow"}) is None  # wrong type: skipped, no crash


def test_cockpit_json_keeps_the_page_keys_and_nulls_non_finite_numbers() -> None:
    assert set(SAMPLE_KEYS) <= {f.name for f in FIELDS}
    full = full_sample()
    sent = json.loads(_sample_json(full))
    assert set(SAMPLE_KEYS) <= set(sent) and sent["h1_ms"] == full.h1_ms
    sample = LeaderSample(t=T, ref_v=math.nan, h1_ms=np.float64(12.5))  # type: ignore[arg-type]
    sent = json.loads(_sample_json(sample))
    assert sent == {"t": T, "ref_v": None, "h1_ms": 12.5}  # unset fields absent, as before
    assert json.loads(sample_to_json(sample)) == sent


def test_the_leader_loop_makes_one_sample_per_command() -> None:
    from bipedtele.config.profile import load_config
    from bipedtele.leader.devices.sim_falcon import SimFalcon
    from bipedtele.leader.loop import LeaderLoop
    from bipedtele.leader.operators.scripted import ScriptedOperator
    from bipedtele.link.inbox import FeedbackInbox
    from bipedtele.link.messages import Command

    cfg = load_config("default", [])
    seen: list[LeaderSample] = []
    observed: list[LeaderSample] = []
    op = ScriptedOperator([[0, 4, -5], [10, 4, -5]], k_g=[160, 200], interp="step")
    op.observe_sample = observed.append  # type: ignore[method-assign]
    dev = SimFalcon()
    dev.connect()
    sent: list[Command] = []
    loop = LeaderLoop(
        dev, op, cfg.control, sent.append, FeedbackInbox(), cfg=cfg.leader, clock=lambda: T, on_sample=seen.append
    )
    loop.run_for(0.5)
    assert len(seen) == len(sent) == 50 and observed == seen
    assert all(isinstance(s, LeaderSample) for s in seen)
    assert [s.seq for s in seen] == [c.seq for c in sent]
    last = seen[-1]
    assert last.operator == "scripted" and last.enable is True and last.link == "waiting"
    assert last.z_e_v is None and last.h1_ms is None  # no feedback yet: unset
    assert json.loads(sample_to_json(last))["ref_v"] == sent[-1].ref[0]
