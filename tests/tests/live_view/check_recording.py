"""Reads a vlnav mission recording with the `mcap` library (PyPI) and its
protobuf decoder (`mcap-protobuf-support`), as a user's own tooling would,
and prints one JSON object: per topic, schema name, schema encoding,
message encoding and count; and facts decoded from the messages themselves.

    python check_recording.py FILE.mcap [FILE.part2.mcap ...]
"""
import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

topics = {}
facts = {
    "frame_seqs_increasing": True,
    "frames": 0,
    "commands": 0,
    "command_mission_ids": [],
    "jpeg_images": 0,
    "target_boxes": 0,
    "labels": [],
    "events": [],
    "plan_steps": None,
    "metadata": {},
    "first_stamp": None,
    "last_stamp": None,
}
last_seq = -1
for path in sys.argv[1:]:
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for record in reader.iter_metadata():
            facts["metadata"][record.name] = dict(record.metadata)
        summary = reader.get_summary()
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            entry = topics.setdefault(
                channel.topic,
                {
                    "schema": schema.name if schema else "",
                    "schema_encoding": schema.encoding if schema else "",
                    "message_encoding": channel.message_encoding,
                    "count": 0,
                },
            )
            entry["count"] += summary.statistics.channel_message_counts.get(cid, 0)
        protobuf = [c.topic for c in summary.channels.values() if c.message_encoding == "protobuf"]
        for schema, channel, message in reader.iter_messages(topics=[c.topic for c in summary.channels.values() if c.message_encoding == "json"]):
            status = json.loads(message.data)
            facts.setdefault("states", [])
            if status["state"] not in facts["states"]:
                facts["states"].append(status["state"])
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=protobuf):
            topic = channel.topic
            if topic.endswith("/sensor_frame"):
                facts["frames"] += 1
                seq = decoded.frame.seq
                if seq <= last_seq:
                    facts["frame_seqs_increasing"] = False
                last_seq = seq
                stamp = decoded.frame.stamp
                if facts["first_stamp"] is None:
                    facts["first_stamp"] = stamp
                facts["last_stamp"] = stamp
            elif topic.endswith("/cmd_vel"):
                facts["commands"] += 1
                if decoded.mission_id not in facts["command_mission_ids"]:
                    facts["command_mission_ids"].append(decoded.mission_id)
            elif topic.endswith("/camera/image"):
                if decoded.format == "jpeg" and decoded.data[:2] == b"\xff\xd8":
                    facts["jpeg_images"] += 1
            elif topic.endswith("/camera/annotations"):
                for text in decoded.texts:
                    label = text.text.rsplit(" ", 1)[0]
                    if label.startswith("TARGET "):
                        facts["target_boxes"] += 1
                    if label not in facts["labels"]:
                        facts["labels"].append(label)
            elif topic.endswith("/mission/events"):
                facts["events"].append(decoded.WhichOneof("kind"))
            elif topic.endswith("/mission/plan"):
                facts["plan_steps"] = len(decoded.steps)
print(json.dumps({"topics": topics, "facts": facts}))
