"""Recordings Foxglove opens: every channel typed by a JSON Schema, read back with the mcap
library and validated message by message; the video as ``foxglove.CompressedImage``;
``read_records`` gives the same maps as before, and still reads the older msgpack files."""

from __future__ import annotations

import base64
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import msgpack
import pytest
from bipedtele.link.messages import Command, Feedback, Status, VideoFrame
from bipedtele.recording.format import message_to_dict, read_records
from bipedtele.recording.recorder import Recorder
from bipedtele.recording.schemas import EVENT_FIELDS, LEADER_STATE_FIELDS, dataclass_schema
from jsonschema import Draft202012Validator
from mcap.reader import make_reader
from mcap.writer import Writer

JPEG = b"\xff\xd8\xff\xe0fake-jpeg-bytes\xff\xd9"
T = 1_790_000_000.0


def leader_state(seq: int) -> dict[str, Any]:
    """A leader sample with every key the leader writes (the table the schema is made of),
    values of the types a run writes, the delay estimates not warm yet (None)."""
    ints = {"seq", "passes_done", "watchdog", "falls", "collisions"}
    sample: dict[str, Any] = {}
    for i, (key, schema) in enumerate(LEADER_STATE_FIELDS.items()):
        types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        if key in ints or "integer" in types:
            sample[key] = seq
        elif "number" in types:
            sample[key] = 0.25 * i - 3.0
        elif "boolean" in types:
            sample[key] = True
        else:
            sample[key] = "walking"
    sample.update(t=T + seq, h1_ms=None, h2_ms=None, delay_ms=None, operator="pilot")
    return sample


EVENTS = [
    {"event": "start", "operator": "pilot"},
    {"event": "pass", "n": 1, "side": "left"},
    {"event": "footfall", "t": T, "robot_t": 2.08, "n": 1, "pose": [0.1, 0.0, 0.01], "step_s": 0.4, "ref": [2.1, 1.4]},
    {"event": "fall", "t": T, "tilt_rad": 0.9, "n": 1},
    {"event": "collision", "t": T, "pose": [1.0, 0.2, 0.1]},
    {"event": "watchdog_stop", "t": T, "why": "no fresh command"},
    {"event": "stop", "elapsed_s": 12.5},
]


def write_every_topic(path: Path) -> list[tuple[str, Any]]:
    """One message (or more) of each topic the leader and the follower write, built with
    the real message classes, through a Recorder; returns what was written, in order."""
    cmd = Command(
        sid=11,
        seq=5,
        t=T,
        ref=[5.0, -4.0],
        x_m=[0.01, -0.02],
        dx_m=[0.1, 0.0],
        h2_s=0.2,
        alpha_m=[3.0, 2.5],
        enable=True,
    )
    fb = Feedback(
        sid=22,
        seq=9,
        t=T + 0.1,
        z_e=[4.0, -3.0],
        z_r=[4.1, -2.9],
        eta=[3.9, -3.2],
        ref=[5.0, -4.0],
        pose=[0.5, -0.1, 0.2],
        sonar=[2.5, 5.0],
        f_v=[0.0, 0.3],
        h1_s=0.15,
        s_e=[1.0, 1.0],
        s_r=[2.0, 2.0],
        T=0.5,
        eps=0.05,
        state="walking",
        cmd_seq=4,
    )
    frames = [
        VideoFrame(sid=22, seq=i, t=T + i, camera="head", width=320, height=240, t_capture=T + i - 0.0125, jpeg=JPEG)
        for i in range(3)
    ]
    f_status = Status(
        sid=22,
        seq=3,
        t=T,
        role="follower",
        state="walking",
        counters={"falls": 1, "collisions": 0, "drop_stale": 2},
        text="ok",
    )
    l_status = Status(sid=11, seq=7, t=T, role="leader", state="running", counters={"commands": 100})
    written: list[tuple[str, Any]] = [
        ("cmd/sent", cmd),
        ("cmd/recv", cmd),
        ("feedback/recv", fb),
        ("feedback/sent", fb),
        *[("video/recv", f) for f in frames],
        ("status/recv", f_status),
        ("status/sent", l_status),
        ("leader/state", leader_state(1)),
        ("leader/state", leader_state(2)),
        *[("events", e) for e in EVENTS],
    ]
    with Recorder(path, jpeg_every=2, metadata={"role": "leader"}) as rec:
        for topic, msg in written:
            assert rec.write(topic, msg, T + 1.0)
    return written


def channels_and_messages(path: Path) -> tuple[dict[str, Any], list[tuple[Any, Any, Any]]]:
    """The channels by topic and every (schema, channel, message), by the mcap library."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {ch.topic: (ch, summary.schemas.get(ch.schema_id)) for ch in summary.channels.values()}
        messages = list(reader.iter_messages())
    return channels, messages


def validate_all(messages: list[tuple[Any, Any, Any]]) -> dict[str, int]:
    """Validate every message against its channel's schema; counts per topic."""
    validators: dict[int, Draft202012Validator] = {}
    counts: dict[str, int] = {}
    for schema, channel, message in messages:
        assert schema is not None, f"{channel.topic}: no schema"
        validator = validators.get(schema.id)
        if validator is None:
            doc = json.loads(schema.data)
            Draft202012Validator.check_schema(doc)
            validator = validators[schema.id] = Draft202012Validator(doc)
        data = json.loads(message.data, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
        errors = [e.message for e in validator.iter_errors(data)]
        assert not errors, f"{channel.topic}: {errors}"
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_every_channel_has_a_json_schema_and_every_message_validates(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_every_topic(path)
    channels, messages = channels_and_messages(path)
    expected = {
        "cmd/sent": "bipedtele.Command",
        "cmd/recv": "bipedtele.Command",
        "feedback/recv": "bipedtele.Feedback",
        "feedback/sent": "bipedtele.Feedback",
        "video/recv": "foxglove.CompressedImage",
        "video/recv/header": "bipedtele.VideoFrameHeader",
        "status/recv": "bipedtele.Status",
        "status/sent": "bipedtele.Status",
        "leader/state": "bipedtele.LeaderState",
        "events": "bipedtele.Event",
    }
    assert {topic: schema.name for topic, (_, schema) in channels.items()} == expected
    for topic, (channel, schema) in channels.items():
        assert channel.message_encoding == "json", topic
        assert schema.encoding == "jsonschema", topic
        assert json.loads(schema.data)["type"] == "object", topic
    counts = validate_all(messages)
    assert counts == {
        "cmd/sent": 1,
        "cmd/recv": 1,
        "feedback/recv": 1,
        "feedback/sent": 1,
        "video/recv": 2,
        "video/recv/header": 1,
        "status/recv": 1,
        "status/sent": 1,
        "leader/state": 2,
        "events": 7,
    }


def test_video_is_a_foxglove_compressed_image(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_every_topic(path)
    _, messages = channels_and_messages(path)
    images = [json.loads(m.data) for s, c, m in messages if c.topic == "video/recv"]
    assert len(images) == 2  # jpeg_every=2: frames 0 and 2 keep their JPEG
    for img, seq in zip(images, (0, 2), strict=True):
        assert base64.b64decode(img["data"]) == JPEG
        assert img["format"] == "jpeg" and img["frame_id"] == "head"
        t_capture = T + seq - 0.0125
        assert img["timestamp"]["sec"] == int(t_capture)
        assert img["timestamp"]["sec"] + img["timestamp"]["nsec"] * 1e-9 == pytest.approx(t_capture, abs=1e-6)
        assert img["seq"] == seq and img["width"] == 320 and img["t_capture"] == t_capture
    schema = next(s for s, c, m in messages if c.topic == "video/recv")
    assert json.loads(schema.data)["properties"]["data"]["contentEncoding"] == "base64"


def test_read_records_returns_the_maps_as_before(tmp_path: Path) -> None:
    """The maps of the msgpack era: a message as message_to_dict, bytes as bytes, a thinned
    frame with an empty JPEG and jpeg_skipped, on the topic it was written to."""
    path = tmp_path / "run.mcap"
    written = write_every_topic(path)
    expected = []
    video_n = 0
    for topic, msg in written:
        if isinstance(msg, VideoFrame):
            data = message_to_dict(msg)
            if video_n % 2:
                data.update(jpeg=b"", jpeg_skipped=True)
            video_n += 1
        else:
            data = message_to_dict(msg) if hasattr(msg, "KIND") else dict(msg)
        expected.append((topic, data))
    got = [(r.topic, r.data) for r in read_records(path)]
    assert got == expected
    assert all(r.t_recv == T + 1.0 for r in read_records(path))


def test_recordings_written_before_the_schemas_still_read(tmp_path: Path) -> None:
    """A file as the msgpack recorder wrote it: channels without a schema, msgpack maps."""
    path = tmp_path / "old.mcap"
    cmd = message_to_dict(Command(seq=3, t=T, ref=[1.0, 2.0]))
    frame = {**message_to_dict(VideoFrame(seq=1, t=T, jpeg=JPEG))}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="bipedtele", library="old")
        ids = {
            t: w.register_channel(topic=t, message_encoding="msgpack", schema_id=0)
            for t in ("cmd/sent", "video/recv", "leader/state")
        }
        for topic, data in (("cmd/sent", cmd), ("video/recv", frame), ("leader/state", {"t": T, "h1_ms": None})):
            w.add_message(
                ids[topic],
                log_time=int(T * 1e9),
                publish_time=int(T * 1e9),
                data=msgpack.packb(data, use_bin_type=True),
            )
        w.finish()
    got = [(r.topic, r.data) for r in read_records(path)]
    assert got == [("cmd/sent", cmd), ("video/recv", frame), ("leader/state", {"t": T, "h1_ms": None})]


def test_undecodable_json_payloads_are_skipped(tmp_path: Path) -> None:
    """A damaged payload (not JSON, not an object, bad base64 in an image) is skipped, the
    messages around it are read."""
    path = tmp_path / "bad.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="bipedtele", library="test")
        sid = w.register_schema(
            name="foxglove.CompressedImage",
            encoding="jsonschema",
            data=json.dumps(
                {"type": "object", "properties": {"data": {"type": "string", "contentEncoding": "base64"}}}
            ).encode(),
        )
        ev = w.register_channel(topic="events", message_encoding="json", schema_id=0)
        img = w.register_channel(topic="video/recv", message_encoding="json", schema_id=sid)
        for cid, payload in (
            (ev, b'{"event": "a"}'),
            (ev, b"{not json"),
            (ev, b"[1, 2]"),
            (img, b'{"k": "video", "data": "***"}'),
            (ev, b'{"event": "b"}'),
        ):
            w.add_message(cid, log_time=1, publish_time=1, data=payload)
        w.finish()
    assert [r.data for r in read_records(path)] == [{"event": "a"}, {"event": "b"}]


def test_the_message_schemas_carry_the_wire_ranges() -> None:
    """The schemas reject what the message decoder rejects: out-of-range, wrong length,
    unknown state, missing field, extra field."""
    v = Draft202012Validator(dataclass_schema(Feedback))
    good = json.loads(json.dumps(message_to_dict(Feedback(seq=1, t=T, state="walking"))))
    assert v.is_valid(good)
    for bad in (
        {**good, "z_e": [2000.0, 0.0]},  # |speed| > 1000
        {**good, "pose": [0.0, 0.0]},  # 3 numbers
        {**good, "state": "dancing"},
        {**good, "k": "cmd"},
        {**good, "cmd_seq": -1},
        {**good, "surprise": 1},
        {k: x for k, x in good.items() if k != "h1_s"},
    ):
        assert not v.is_valid(bad), bad
    status = Draft202012Validator(dataclass_schema(Status))
    good_status = message_to_dict(Status(t=T, counters={"falls": 2}))
    assert status.is_valid(good_status)
    assert not status.is_valid({**good_status, "counters": {"falls": -1}})


def test_nonfinite_numbers_are_written_as_null(tmp_path: Path) -> None:
    path = tmp_path / "nan.mcap"
    with Recorder(path) as rec:
        assert rec.write("leader/state", {"t": T, "force_v": math.nan, "extra": [1.0, math.inf]}, T)
    assert rec.stats["nonfinite_nulled"] == 1
    _, messages = channels_and_messages(path)
    validate_all(messages)  # strict JSON (no NaN token) that fits the schema
    assert [r.data for r in read_records(path)] == [{"t": T, "force_v": None, "extra": [1.0, None]}]


def test_map_schemas_type_the_keys_of_the_first_map(tmp_path: Path) -> None:
    path = tmp_path / "maps.mcap"
    with Recorder(path) as rec:
        rec.write("estimates", {"h1_s": 0.1, "label": "a", "ok": True, "blob": b"\x00\x01", "v": [1, 2.5]}, T)
        rec.write("estimates", {"h1_s": None, "label": "b", "ok": False, "blob": b"", "v": [], "later": 3}, T)
        rec.write("events", {"event": "custom", "detail": "x"}, T)
    channels, messages = channels_and_messages(path)
    props = json.loads(channels["estimates"][1].data)["properties"]
    assert props["h1_s"]["type"] == ["number", "null"] and props["ok"]["type"] == ["boolean", "null"]
    assert props["blob"]["contentEncoding"] == "base64" and props["v"]["items"]["type"] == ["number", "null"]
    events = json.loads(channels["events"][1].data)
    assert set(EVENT_FIELDS) <= set(events["properties"]) and events["required"] == ["event"]
    validate_all(messages)
    got = [r.data for r in read_records(path)]
    assert got[0]["blob"] == b"\x00\x01" and got[1]["blob"] == b""  # bytes come back as bytes
    assert got[1]["later"] == 3 and got[2] == {"event": "custom", "detail": "x"}


@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_a_demo_recording_has_typed_channels_that_validate(tmp_path: Path) -> None:
    """The issue's check: ``bipedtele demo --record`` (router, delay proxy, pybullet follower
    with its camera, leader), both recordings read back with the mcap library, every
    message of every channel valid against its schema."""
    run_dir, record = tmp_path / "run", tmp_path / "leader.mcap"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "demo",
            "--headless",
            "--quiet",
            "--duration",
            "8",
            "--run-dir",
            str(run_dir),
            "--record",
            str(record),
        ],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    channels, messages = channels_and_messages(record)
    leader = validate_all(messages)
    for topic in ("cmd/sent", "feedback/recv", "leader/state", "status/recv", "video/recv", "events"):
        assert leader.get(topic, 0) > 0, (topic, leader)
    assert channels["video/recv"][1].name == "foxglove.CompressedImage"
    follower_files = sorted(run_dir.glob("follower*.mcap"))
    assert follower_files, sorted(p.name for p in run_dir.iterdir())
    follower = validate_all(channels_and_messages(follower_files[0])[1])
    for topic in ("cmd/recv", "feedback/sent", "status/sent"):
        assert follower.get(topic, 0) > 0, (topic, follower)
