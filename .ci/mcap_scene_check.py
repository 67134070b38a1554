#!/usr/bin/env python3
"""Checks the Foxglove scene topics of a voxhap MCAP recording with the `mcap` PyPI package, an MCAP reader
independent of voxhap's: every topic the shipped Foxglove layout shows is in the recording, and each topic
comes at its documented rate (docs/foxglove.md, "Topics"); what Foxglove Studio and Lichtblick need to open
the file holds: every chunk holds messages and their message index, the statistics' start and end are the first
and last message's log times, and every JSON schema passes the viewers' JSON-schema reader (`schema_problem`,
rule for rule from Lichtblick's packages/mcap-support/src/parseJsonSchema.ts).

Usage: mcap_scene_check.py RECORDING.mcap LAYOUT.json [PICTURES=1]
       mcap_scene_check.py --viewer-only RECORDING.mcap   (only what the viewers need to open the file)
PICTURES is how many volume pictures the recording must hold: 1, plus one per volume loaded while
recording; each comes with its two frames (`volume` and `volume_view`, the camera framing), in log-time order.
Prints one JSON report line on success; exits 1 with the reason otherwise. Run by tests/foxglove.rs
(python_mcap_reads_the_scene_topics_of_a_recorded_session) and tests/foxglove_scene_change.rs (a volume
loaded mid-recording, PICTURES=2), which skip visibly without python3 or mcap.
"""
import json
import sys
import time

from mcap.reader import make_reader


def fail(message):
    print(f"mcap_scene_check: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def check(condition, message):
    if not condition:
        fail(message)


# The topic that publishes each frame the layout's 3D panel follows or lists.
FRAME_TOPICS = {
    "volume": "/voxhap/volume_frame",
    "volume_view": "/voxhap/volume_frame",
    "probe": "/voxhap/measured_cp",
    "proxy": "/voxhap/setpoint_cp",
}


SCALARS = ("boolean", "string", "number", "integer")


def schema_problem(schema, path):
    """What Lichtblick's / Foxglove Studio's parseJsonSchema refuses in a JSON schema, or None: the root and every
    nested object is "type": "object" with "properties"; each field's "type" is one of boolean, string, number,
    integer, object, array (a list such as ["number", "null"] or no type is refused); array items likewise."""
    if schema.get("type") != "object":
        return f"{path}: type {schema.get('type')!r}, not 'object'"
    if not isinstance(schema.get("properties"), dict):
        return f"{path}: an object without properties"
    for name, field in schema["properties"].items():
        at = f"{path}.{name}"
        kind = field.get("type")
        if kind == "object":
            problem = schema_problem(field, at)
            if problem:
                return problem
        elif kind == "array":
            items = field.get("items", {})
            if items.get("type") == "object":
                problem = schema_problem(items, at)
                if problem:
                    return problem
            elif items.get("type") not in SCALARS:
                return f"{at}: array item type {items.get('type')!r}"
        elif kind not in SCALARS:
            return f"{at}: field type {kind!r}"
    return None


def check_viewer_requirements(path):
    """The file as Foxglove Studio and the @mcap/core that Lichtblick pins need it (see the module doc)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        check(summary is not None and summary.statistics is not None, "no summary with statistics")
        log_times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
    check(log_times, "no messages")
    for i, chunk in enumerate(summary.chunk_indexes):
        check(chunk.message_index_offsets, f"chunk {i} has no message index (no messages)")
        check(chunk.message_start_time >= min(log_times), f"chunk {i} starts at {chunk.message_start_time}, before the first message")
    stats = summary.statistics
    check(stats.message_start_time == min(log_times) == log_times[0],
          f"statistics start {stats.message_start_time}, first message {log_times[0]}")
    check(stats.message_end_time == max(log_times), f"statistics end {stats.message_end_time}, last message {max(log_times)}")
    for schema in summary.schemas.values():
        if schema.encoding == "jsonschema":
            problem = schema_problem(json.loads(schema.data), schema.name)
            check(problem is None, f"Foxglove/Lichtblick refuse the JSON schema {problem}")
    return len(summary.chunk_indexes)


def layout_topics(layout):
    """Topics a Foxglove layout refers to: 3D panel topics and frames, plot/state paths, raw-message topics."""
    topics = set()
    for panel in layout["configById"].values():
        topics.update(panel.get("topics", {}).keys())
        for path in panel.get("paths", []):
            topics.add(path["value"].split(".")[0])
        if "topicPath" in panel:
            topics.add(panel["topicPath"].split(".")[0])
        if "followTf" in panel:
            topics.add(FRAME_TOPICS[panel["followTf"]])
        for key in panel.get("transforms", {}):
            topics.add(FRAME_TOPICS[key.removeprefix("frame:")])
    return topics


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--viewer-only":
        print(json.dumps({"chunks": check_viewer_requirements(sys.argv[2])}))
        return
    if len(sys.argv) not in (3, 4):
        fail("usage: mcap_scene_check.py RECORDING.mcap LAYOUT.json [PICTURES]")
    pictures = int(sys.argv[3]) if len(sys.argv) == 4 else 1
    with open(sys.argv[2]) as f:
        wanted = layout_topics(json.load(f))
    chunks = check_viewer_requirements(sys.argv[1])
    counts, schemas, first, last, sizes, first_json = {}, {}, {}, {}, {}, {}
    picture_times, frame_times = [], []
    with open(sys.argv[1], "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = [schema.name, schema.encoding, channel.message_encoding]
            sizes[topic] = max(sizes.get(topic, 0), len(message.data))
            check(message.log_time >= last.get(topic, 0), f"{topic}: log times go backwards")
            first.setdefault(topic, message.log_time)
            last[topic] = message.log_time
            if topic == "/voxhap/volume":
                picture_times.append(message.log_time)
            if topic == "/voxhap/volume_frame":
                frame_times.append(message.log_time)
            if channel.message_encoding == "json" and topic not in first_json:
                first_json[topic] = json.loads(message.data)

    missing = sorted(t for t in wanted if counts.get(t, 0) == 0)
    check(not missing, f"the layout shows {missing}, which the recording does not carry")

    # Rates over the recording's span of ticks (setpoint_cf: one message per tick).
    ticks = counts["/voxhap/setpoint_cf"]
    span_s = (last["/voxhap/setpoint_cf"] - first["/voxhap/setpoint_cf"]) / 1e9
    check(span_s > 1.0, f"recording only {span_s:.3f} s long")
    for topic in ("/voxhap/measured_cp", "/voxhap/setpoint_cp", "/voxhap/state", "/voxhap/solver"):
        check(counts[topic] == ticks, f"{topic}: {counts[topic]} messages for {ticks} ticks")
    check(len(picture_times) == pictures, f"{len(picture_times)} volume pictures, expected {pictures}")
    check(picture_times == sorted(set(picture_times)), f"volume pictures' log times not increasing: {picture_times}")
    check(frame_times == [t for t in picture_times for _ in range(2)], "not two volume frames with each picture")
    check(sizes["/voxhap/volume"] > 20_000, f"volume message of {sizes['/voxhap/volume']} bytes: no mesh?")
    rates = {topic: counts[topic] / span_s for topic in counts}
    # The scene follows the servo's snapshots: at most 60 Hz of tick time, fewer on a busy machine (no lower rate).
    scene = rates["/voxhap/primitives"]
    check(counts["/voxhap/primitives"] > 0 and scene <= 60.0 + 2.0 / span_s, f"/voxhap/primitives at {scene:.1f} Hz, at most 60")
    for topic in ("/voxhap/bound", "/voxhap/operating_state"):
        check(counts[topic] == counts["/voxhap/primitives"], f"{topic}: {counts[topic]} messages")
    for axis in "xyz":
        topic = f"/voxhap/volume/slice_{axis}"
        check(schemas[topic][0] == "foxglove.Grid", f"{topic} schema {schemas[topic]}")
        # A new volume's slices start at its picture: up to one extra set per change.
        expected = span_s / 0.25 + 1
        check(-1.5 <= counts[topic] - expected <= 1.5 + (pictures - 1), f"{topic}: {counts[topic]} in {span_s:.2f} s (4 Hz)")
    check(abs(counts["/voxhap/stats"] - span_s) <= 1.5, f"/voxhap/stats: {counts['/voxhap/stats']} in {span_s:.2f} s")

    # The JSON topics decode to what the layout's panels plot.
    check(first_json["/voxhap/operating_state"]["state"] in ("ENABLED", "DISABLED"), "operating_state.state")
    bound = first_json["/voxhap/bound"]
    check("status" in bound, "/voxhap/bound has no status")
    # error_bound_m is left out of a tick without a certificate.
    check(bound["status"] not in ("certified", "budget_exhausted") or isinstance(bound.get("error_bound_m"), (int, float)),
          f"/voxhap/bound without error_bound_m: {bound}")
    stats = first_json["/voxhap/stats"]
    check(stats["t_s"] >= 1.0 and stats["ticks"] > 0, f"first statistics {stats}")

    # Log times are wall-clock UTC.
    now_ns = time.time_ns()
    check(0 < now_ns - first["/voxhap/setpoint_cf"] < 120e9, f"first log time {first['/voxhap/setpoint_cf']}, now {now_ns}")
    print(json.dumps({"chunks": chunks, "counts": counts, "rates_hz": rates, "span_s": span_s, "schemas": schemas,
                      "picture_log_times": picture_times,
                      "layout_topics": sorted(wanted)}))


if __name__ == "__main__":
    main()
