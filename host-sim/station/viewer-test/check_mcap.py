"""Replay a base station's MCAP (a `--record` or a `map-query --mcap` export) in PyPI's `mcap` reader and
check it against `map-info` / `map-query`, as check.js does for the live view.

Usage: python3 check_mcap.py FILE.mcap expect.json

Scene updates are applied in log order as Foxglove applies them (entities replace entities of the same
id; deletions by id or all); protobuf messages are decoded with the schema the file carries
(mcap-protobuf-support), JSON ones with json. At the end the classes layer must hold exactly the map's
voxels with map-query's classes, and the heat layer's top voxels must be map-query --query's.
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


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
            if channel.id not in decoders:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            msg = decoders[channel.id](message.data)
            entities = layers.setdefault(channel.topic, {})
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
                assert len(keys) == len(e.cubes) == len(values), (channel.topic, e.id)
                entities[e.id] = (keys, values)

    def voxels(topic):
        out = {}
        for keys, values in layers.get(topic, {}).values():
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


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
