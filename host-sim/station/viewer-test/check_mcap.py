"""Replay a base station's MCAP (a `--record` or a `map-query --mcap` export) in PyPI's `mcap` reader and
check it against `map-info` / `map-query`, as check.js does for the live view; or check that it seeks.

Usage: python3 check_mcap.py FILE.mcap expect.json
       python3 check_mcap.py --seek FILE.mcap
       python3 check_mcap.py --legend FILE.mcap   (prints the last legend and the last scene's colours, JSON)

`--seek`: at every time a message was logged, a reader that seeks there (the file's index, newest message
of each topic at or before that time, read backwards: what Foxglove and Lichtblick show after a seek)
must rebuild from that one message per layer the same scene as a reader that applied every message from
the start, and that scene must be whole (as many voxels as the legend of that time counts). The file must
open on a map (at its first time, /map/classes holds voxels), and its last scene shows each class that has
voxels in a distinct colour, named by the legend.

Scene updates are applied in log order as Foxglove applies them (entities replace entities of the same
id; deletions by id or all); protobuf messages are decoded with the schema the file carries
(mcap-protobuf-support), JSON ones with json. At the end the classes layer must hold exactly the map's
voxels with map-query's classes, and the heat layer's top voxels must be map-query --query's.
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def apply(entities, msg):
    """A SceneUpdate applied as Foxglove applies it: deletions (by id, or all), then entities by id."""
    for d in msg.deletions:
        if d.type == 1:
            entities.clear()
        else:
            entities.pop(d.id, None)
    for e in msg.entities:
        meta = {kv.key: kv.value for kv in e.metadata}
        keys = meta["voxels"].split(",") if meta.get("voxels") else []
        values = [kv.value for kv in e.metadata if kv.key != "voxels"][0]
        values = values.split(",") if values else [""] * len(keys)
        colours = [
            (round(c.color.r * 255), round(c.color.g * 255), round(c.color.b * 255)) for c in e.cubes
        ]
        assert len(keys) == len(e.cubes) == len(values), e.id
        entities[e.id] = (keys, values, colours)
    return entities


def voxel_count(entities):
    return sum(len(keys) for keys, _, _ in entities.values())


def seek(path):
    factory = DecoderFactory()
    decoders = {}
    decoded = {}  # (channel id, log time) -> decoded message
    layers = {}
    legend = None
    problems = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        scene_topics = sorted(
            c.topic
            for c in summary.channels.values()
            if summary.schemas[c.schema_id].name == "foxglove.SceneUpdate"
        )
        messages = list(reader.iter_messages(log_time_order=True))
        times = sorted({m.log_time for _, _, m in messages})
        legend_at = {}
        i = 0
        checked = 0
        snapshots = []
        for t in times:
            # The reader from the start: every message up to t.
            while i < len(messages) and messages[i][2].log_time <= t:
                schema, channel, message = messages[i]
                i += 1
                if channel.message_encoding == "json":
                    if channel.topic == "/map/legend":
                        legend = json.loads(message.data)
                    continue
                if channel.topic not in scene_topics:
                    continue
                if channel.id not in decoders:
                    decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                msg = decoders[channel.id](message.data)
                decoded[(channel.id, message.log_time)] = msg
                apply(layers.setdefault(channel.topic, {}), msg)
                if channel.topic == "/map/classes":
                    snapshots.append(voxel_count(layers[channel.topic]))
            legend_at[t] = legend
            # The reader that seeks to t: the newest message of each topic at or before t, alone.
            for topic in scene_topics:
                back = next(reader.iter_messages(topics=[topic], ending_at=t, reverse=True), None)
                fresh = {} if back is None else apply({}, decoded[(back[1].id, back[2].log_time)])
                if fresh != layers.get(topic, {}):
                    problems.append(
                        f"at {t}: {topic} after a seek holds {voxel_count(fresh)} voxels, "
                        f"read from the start {voxel_count(layers.get(topic, {}))}"
                    )
                    break
            # The heat cloud a seek finds holds the heat layer's voxels.
            back = next(reader.iter_messages(topics=["/map/heat_cloud"], ending_at=t, reverse=True), None)
            if back is not None and "/map/heat" in layers:
                schema, channel, message = back
                if channel.id not in decoders:
                    decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                cloud = decoders[channel.id](message.data)
                points = len(cloud.data) // cloud.point_stride
                if points != voxel_count(layers["/map/heat"]):
                    problems.append(
                        f"at {t}: the heat cloud holds {points} points, the heat layer {voxel_count(layers['/map/heat'])} voxels"
                    )
            classes = layers.get("/map/classes", {})
            if legend is None or "undecoded" not in legend:
                if classes:
                    problems.append(f"at {t}: no legend counting the scene's voxels")
            elif classes:
                counted = sum(c["voxels"] for c in legend["classes"]) + legend["undecoded"]["voxels"]
                if counted != voxel_count(classes):
                    problems.append(
                        f"at {t}: the scene holds {voxel_count(classes)} voxels, the legend counts {counted}"
                    )
            checked += 1
            if problems:
                break
        first = next(reader.iter_messages(topics=["/map/classes"], ending_at=times[0]), None)
        opens_on = 0 if first is None else voxel_count(apply({}, decoded[(first[1].id, first[2].log_time)]))
    if opens_on == 0:
        problems.append("the file opens on an empty /map/classes")
    last = layers.get("/map/classes", {})
    per_class = {}
    for _, values, colours in last.values():
        for v, c in zip(values, colours):
            per_class.setdefault(v, set()).add(c)
    distinct = {c for cs in per_class.values() for c in cs}
    if legend is None or not legend.get("classes"):
        problems.append("no legend with classes")
    elif any(not c.get("class") for c in legend["classes"]):
        problems.append(f"legend entries without a name: {legend['classes']}")
    if len(distinct) < len(per_class):
        problems.append(f"{len(distinct)} distinct colours for {len(per_class)} classes")
    if problems:
        print(f"mcap-seek {path}: FAILED: " + "; ".join(problems))
        return 1
    names = ", ".join(c["class"] for c in legend["classes"])
    print(
        f"mcap-seek {path}: ok: {len(snapshots)} snapshots of /map/classes ({min(snapshots)} to "
        f"{max(snapshots)} voxels); at each of {checked} message times a seek (newest message per topic) "
        f"rebuilds the scene read from the start, whole (= the legend's count); opens on {opens_on} voxels; "
        f"last scene {voxel_count(last)} voxels in {len(distinct)} distinct class colours for "
        f"{len(per_class)} classes with voxels, legend names {len(legend['classes'])} ({names})"
    )
    return 0


def main(path, expect_path):
    expect = json.load(open(expect_path))
    factory = DecoderFactory()
    decoders = {}
    layers = {}
    legend = None
    status = None
    messages = 0
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            messages += 1
            if channel.message_encoding == "json":
                msg = json.loads(message.data)
                if channel.topic == "/map/legend":
                    legend = msg
                elif channel.topic == "/link/status":
                    status = msg
                continue
            if schema.name != "foxglove.SceneUpdate":
                continue  # the centre frame (/tf), the heat cloud
            if channel.id not in decoders:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            apply(layers.setdefault(channel.topic, {}), decoders[channel.id](message.data))

    def voxels(topic):
        out = {}
        for keys, values, _ in layers.get(topic, {}).values():
            out.update(zip(keys, values))
        return out

    classes = voxels("/map/classes")
    problems = []
    if len(classes) != expect["count"]:
        problems.append(f"{len(classes)} voxels, map-info says {expect['count']}")
    counts = [0] * len(expect["class_counts"])
    for k, v in classes.items():
        want = expect["classes"].get(k)
        if want is None or str(want) != v:
            problems.append(f"voxel {k}: class {v}, map-query says {want}")
            break
        counts[int(v)] += 1
    if counts != expect["class_counts"]:
        problems.append(f"class counts {counts}, map-query says {expect['class_counts']}")
    heat = sorted(
        ((k, float(s)) for k, s in voxels("/map/heat").items() if s != ""), key=lambda kv: -kv[1]
    )
    top = [k for k, _ in heat[: len(expect["top_keys"])]]
    if sorted(top) != sorted(expect["top_keys"]):
        problems.append(f"heat top {top}, map-query --query ranks {expect['top_keys']}")
    if legend is None or legend.get("query") != expect["phrase"]:
        problems.append(f"legend {legend}")
    if problems:
        print(f"mcap-check {path}: FAILED: " + "; ".join(problems))
        return 1
    frames = status["frames"] if status else "none (an export)"
    print(
        f"mcap-check {path}: ok: {len(classes)} voxels and classes equal map-info/map-query, "
        f"heat top {len(top)} for \"{expect['phrase']}\" equals map-query --query; "
        f"{messages} messages; link frames {frames}"
    )
    return 0


def last_legend(path):
    factory = DecoderFactory()
    legend, classes = None, None
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.topic == "/map/legend":
                legend = json.loads(message.data)
            elif channel.topic == "/map/classes":
                classes = apply({}, factory.decoder_for(channel.message_encoding, schema)(message.data))
    colours = sorted({"#%02x%02x%02x" % c for _, _, cs in (classes or {}).values() for c in cs})
    print(json.dumps({"legend": legend, "colours": colours}))
    return 0


if __name__ == "__main__":
    if sys.argv[1] == "--seek":
        sys.exit(seek(sys.argv[2]))
    if sys.argv[1] == "--legend":
        sys.exit(last_legend(sys.argv[2]))
    sys.exit(main(sys.argv[1], sys.argv[2]))
