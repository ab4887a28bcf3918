"""The recording is a plain MCAP file: the mcap library reads every channel, JSON schemas and JSON messages."""

from __future__ import annotations

import json
from collections import Counter

import pytest
from mcap.reader import make_reader

from swarm.view import record, report

pytestmark = pytest.mark.unit

TYPES = {"number": (int, float), "integer": (int,), "boolean": (bool,), "string": (str,), "array": (list,),
         "object": (dict,), "null": (type(None),)}


def _is(value, kind: str) -> bool:
    if kind in ("number", "integer") and isinstance(value, bool):
        return False
    return isinstance(value, TYPES[kind])


def check(schema: dict, msg: dict, where: str) -> None:
    """JSON Schema in spirit: required keys, no unknown keys unless allowed, types (and array items), enums."""
    assert isinstance(msg, dict), where
    missing = [k for k in schema["required"] if k not in msg]
    assert not missing, f"{where}: missing {missing}"
    if schema.get("additionalProperties") is False:
        extra = set(msg) - set(schema["properties"])
        assert not extra, f"{where}: unknown keys {extra}"
    for key, spec in schema["properties"].items():
        if key not in msg:
            continue
        kinds = spec["type"] if isinstance(spec["type"], list) else [spec["type"]]
        assert any(_is(msg[key], k) for k in kinds), f"{where}: {key} = {msg[key]!r} is not {kinds}"
        if "enum" in spec:
            assert msg[key] in spec["enum"], f"{where}: {key} = {msg[key]!r} not in {spec['enum']}"
        if spec["type"] == "array":
            item = spec["items"]["type"]
            assert all(_is(v, item) for v in msg[key]), f"{where}: {key} has items that are not {item}"


FOXGLOVE_TYPES = {"boolean", "string", "number", "integer", "object", "array"}


def foxglove_readable(schema: dict, where: str) -> None:
    """What Foxglove's JSON Schema reader accepts (packages/mcap-support parseJsonSchema): an object whose
    every property has exactly one type (no ["number", "null"] lists), arrays of one item type."""
    assert schema["type"] == "object", where
    for key, spec in schema["properties"].items():
        assert isinstance(spec.get("type"), str) and spec["type"] in FOXGLOVE_TYPES, f"{where}.{key}: {spec}"
        if spec["type"] == "array":
            assert spec["items"].get("type") in FOXGLOVE_TYPES - {"array"}, f"{where}.{key}: {spec}"
        if spec["type"] == "object":
            foxglove_readable(spec, f"{where}.{key}")


def test_every_schema_is_readable_by_foxglove():
    for topic, (name, schema) in record.SCHEMAS.items():
        foxglove_readable(schema, name)
        assert set(schema["required"]) <= set(schema["properties"])


def read_all(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        out = [(schema, channel, message) for schema, channel, message in reader.iter_messages()]
    return summary, out


@pytest.mark.parametrize("which", ["sim_run", "live_run", "sim_faults_run", "live_faults_run"])
def test_mcap_reads_every_channel_and_every_message_matches_its_schema(which, request):
    run = request.getfixturevalue(which)
    summary, messages = read_all(run.path)
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) == set(record.TOPICS)
    for topic, channel in topics.items():
        schema = summary.schemas[channel.schema_id]
        assert channel.message_encoding == "json"
        assert schema.encoding == "jsonschema"
        assert schema.name == record.SCHEMAS[topic][0]
        body = json.loads(schema.data)
        assert body["type"] == "object" and set(body["required"]) <= set(body["properties"])
    counts = Counter()
    for schema, channel, message in messages:
        msg = json.loads(message.data)
        check(json.loads(schema.data), msg, f"{channel.topic} at {message.log_time}")
        counts[channel.topic] += 1
        if channel.topic == "/metrics":  # the nullable contract keys, not declared for Foxglove's sake
            for key in record.NULLABLE_METRICS:
                assert msg[key] is None or _is(msg[key], "number"), (key, msg[key])
        if channel.topic == "/events":
            assert all(msg.get(k) is not None for k in ("robot", "other", "obstacle", "distance") if k in msg)
        if "t" in msg:  # the time base: log_time is simulated time in ns
            assert message.log_time == round(msg["t"] * 1e9)
    kinds = {"sim_run": {"/scenario", "/world/snapshot", "/leader/ref", "/robot/cmd", "/robot/status", "/events",
                         "/metrics"},
             "live_run": set(record.TOPICS) - {"/faults"}}  # no fault: no fault event
    assert set(counts) == kinds.get(which, set(record.TOPICS))
    assert counts["/scenario"] == 1 and counts["/metrics"] == 1
    assert report.read_recording(run.path).counts == dict(counts)
    assert summary.statistics.message_count == len(messages)
    with open(run.path, "rb") as f:  # in the order written: the scenario first, the metrics last
        written = [(c.topic, m.log_time) for _s, c, m in make_reader(f).iter_messages(log_time_order=False)]
    assert written[0] == ("/scenario", 0)
    assert written[-1][0] == "/metrics" and written[-1][1] == max(t for _topic, t in written)


def test_scenario_message_rebuilds_the_scenario(sim_run):
    from swarm.core import scenario_file

    _summary, messages = read_all(sim_run.path)
    msg = json.loads(next(m.data for _s, c, m in messages if c.topic == "/scenario"))
    scn = sim_run.scenario
    assert (msg["name"], msg["robots"], msg["dt"], msg["duration"], msg["seed"]) == \
           (scn.name, scn.n, scn.dt, scn.duration, scn.seed)
    assert msg["toml"] == scenario_file.to_toml(scn)
    assert msg["source"] == "sim" and msg["record_hz"] == 20.0 and msg["record_every"] == 2


def test_bad_record_hz_is_refused(tmp_path, sim_run):
    for bad in (-1.0, float("nan"), float("inf"), True):
        with pytest.raises(record.RecordError, match="record_hz"):
            record.Recorder(tmp_path / "x.mcap", sim_run.scenario, bad)


def test_unwritable_path_names_the_file(tmp_path, sim_run):
    target = tmp_path / "no" / "such" / "dir" / "x.mcap"
    with pytest.raises(record.RecordError, match="no/such/dir/x.mcap"):
        record.Recorder(target, sim_run.scenario, 20.0)
