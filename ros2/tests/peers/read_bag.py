"""Reads a rosbag2 bag with PyPI `rosbags` (not TES code) topic by topic.

    python read_bag.py BAG_DIR

Registers each topic's type from the definition the bag carries, decodes every message with
it and again with rosbags' own ROS 2 Humble and Jazzy types (so the bag's layouts are ROS 2's),
and prints one JSON object: per topic, its type, count, durability and the last message."""

import json
import sys

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def last_of(topic, m):
    if topic == "/tf":
        t = m.transforms[0]
        return {"parent": t.header.frame_id, "child": t.child_frame_id}
    if topic == "/tes/arena":
        return {"markers": len(m.markers)}
    if topic == "/tes/path":
        return {"poses": len(m.poses)}
    if topic == "/rosout":
        return {"name": m.name, "msg": m.msg}
    return {"data": m.data}


def main():
    own = get_typestore(Stores.EMPTY)
    stores = [get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS2_JAZZY)]
    out = {}
    with Reader(sys.argv[1]) as reader:
        for c in reader.connections:
            own.register(get_types_from_msg(c.msgdef.data, c.msgtype))
            qos = c.ext.offered_qos_profiles
            out[c.topic] = {
                "type": c.msgtype,
                "count": 0,
                "durability": qos[0].durability.name.lower() if qos else None,
            }
        for c, _stamp, raw in reader.messages():
            m = own.deserialize_cdr(raw, c.msgtype)
            for store in stores:
                store.deserialize_cdr(raw, c.msgtype)
            out[c.topic]["count"] += 1
            out[c.topic]["last"] = last_of(c.topic, m)
        out["message_count"] = reader.message_count
    print(json.dumps(out))


if __name__ == "__main__":
    main()
