"""A ROS 2 peer on Eclipse Cyclone DDS that listens to a TES group's topics.

    python listen.py DOMAIN SECONDS [--until-stdin-closes]

Subscribes, with ROS 2's DDS names (`rt/<topic>`) and types, to every topic the group
publishes; prints `ready` once subscribed, then, when each topic has had a message or the
time is up, one JSON object: per topic, the messages received and what the last said.
With `--until-stdin-closes` it listens until its standard input closes (or the time is up),
prints `matched` once every reader has matched a publisher (DDS discovery is done: what is
published from then on reaches it), and also keeps every episode's end and reward, in the
order they came."""

import json
import sys
import threading
import time

from cyclonedds.core import Qos, Policy
from cyclonedds.domain import DomainParticipant
from cyclonedds.internal import InvalidSample
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

import ros2_types as t

# (topic, type, latched) as docs/ros2.md lists them.
TOPICS = [
    ("/tf", t.TFMessage, False),
    ("/tes/arena", t.MarkerArray, True),
    ("/tes/path", t.Path, False),
    ("/tes/decision/action", t.UInt32, False),
    ("/tes/decision/latency_us", t.Float64, False),
    ("/tes/episode/reward", t.Float64, False),
    ("/tes/episode/end", t.String, False),
    ("/rosout", t.Log, True),
]


def summary(name, m):
    if name == "/tf":
        tf = m.transforms[0]
        v = tf.transform.translation
        return {"parent": tf.header.frame_id, "child": tf.child_frame_id, "x": v.x, "y": v.y,
                "stamp_sec": tf.header.stamp.sec}
    if name == "/tes/arena":
        return {"markers": len(m.markers), "frames": sorted({k.header.frame_id for k in m.markers}),
                "types": [k.type for k in m.markers]}
    if name == "/tes/path":
        return {"frame": m.header.frame_id, "poses": len(m.poses)}
    if name == "/rosout":
        return {"name": m.name, "level": m.level, "msg": m.msg}
    return {"data": m.data}


KEPT = ("/tes/episode/end", "/tes/episode/reward")


def main():
    domain, seconds = int(sys.argv[1]), float(sys.argv[2])
    whole_run = "--until-stdin-closes" in sys.argv[3:]
    closed = threading.Event()
    if whole_run:
        threading.Thread(target=lambda: (sys.stdin.read(), closed.set()), daemon=True).start()
    participant = DomainParticipant(domain)
    readers = {}
    for name, kind, latched in TOPICS:
        qos = Qos(
            Policy.Reliability.Reliable(duration(milliseconds=100)),
            Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
            Policy.History.KeepLast(1000),
        )
        readers[name] = DataReader(participant, Topic(participant, "rt" + name, kind), qos=qos)
    print("ready", flush=True)
    got = {name: {"count": 0} for name, _, _ in TOPICS}
    for name in KEPT:
        got[name]["all"] = []

    def take():
        for name, reader in readers.items():
            for m in reader.take(N=100):
                if isinstance(m, InvalidSample):
                    # An instance's state change (a writer gone at the run's end), no data.
                    continue
                got[name]["count"] += 1
                got[name]["last"] = summary(name, m)
                if name in KEPT:
                    got[name]["all"].append(m.data)

    def done():
        if whole_run:
            return closed.is_set()
        return all(g["count"] for g in got.values())

    matched = False
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not done():
        take()
        if whole_run and not matched and all(r.get_matched_publications() for r in readers.values()):
            matched = True
            print("matched", flush=True)
        time.sleep(0.05)
    # A little more for the messages that were on their way.
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        take()
        time.sleep(0.05)
    print(json.dumps(got), flush=True)


if __name__ == "__main__":
    main()
