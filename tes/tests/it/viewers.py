"""What independent clients see of a TES run drawn for viewers.

    viewers.py mcap FILE.mcap        PyPI's mcap and Foxglove's Protobuf schemas read a recording
    viewers.py rerun FILE.mcap RRD   Rerun converts it, checks it and reads the result back
    viewers.py native FILE.mcap RRD  python/tes/rerun_view.py draws it with Rerun's own
                                     archetypes; rerun-sdk's reader reads the .rrd back
    viewers.py native-live HOST:PORT RRD SECONDS
                                     the same, following a live group
    viewers.py live HOST:PORT N      a Foxglove WebSocket client follows a live group for N episodes
    viewers.py names HOST:PORT       a client offering each name of the protocol, one after the other

Each prints one JSON object of facts for the Rust test to judge.
"""
import contextlib
import json
import struct
import subprocess
import sys
import time


def facts_of_recording(path):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    facts = {"channels": {}, "ordered": {}, "decisions": [], "episodes": [], "logs": [],
             "tf": [], "arena": None, "robot_entities": set()}
    last_time = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        counts = summary.statistics.channel_message_counts
        for c in summary.channels.values():
            s = summary.schemas[c.schema_id]
            facts["channels"][c.topic] = [s.name, s.encoding, c.message_encoding, counts.get(c.id, 0)]
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=["/arena", "/tf", "/robot", "/log", "/tes/decision", "/tes/episode",
                        "/arena/points", "/robot/pose", "/robot/path"]):
            t = channel.topic
            facts["ordered"][t] = facts["ordered"].get(t, True) and message.log_time >= last_time.get(t, 0)
            last_time[t] = message.log_time
            if t == "/arena":
                typed = SceneUpdate.FromString(message.data)
                e = typed.entities[0]
                facts["arena"] = {"frame": e.frame_id, "cubes": len(e.cubes),
                                  "cylinders": len(e.cylinders), "spheres": len(e.spheres),
                                  "floor_m": e.cubes[0].size.x}
            elif t == "/tf":
                typed = FrameTransform.FromString(message.data)
                assert str(typed) == str(decoded), "Foxglove's classes and the file's schema agree"
                facts["tf"].append([typed.parent_frame_id, typed.child_frame_id,
                                    typed.translation.x, typed.translation.y])
            elif t == "/robot":
                for e in decoded.entities:
                    facts["robot_entities"].add(e.id)
            elif t == "/log":
                facts["logs"].append([decoded.name, decoded.level, decoded.message[:80]])
            elif t == "/tes/decision":
                facts["decisions"].append([decoded.action_name, decoded.latency_us])
            elif t == "/tes/episode":
                facts["episodes"].append([decoded.episode, decoded.reward, decoded.outcome])
    facts["robot_entities"] = sorted(facts["robot_entities"])
    return facts


def facts_of_rerun(mcap_path, rrd_path):
    import rerun.chunk as chunk
    rerun = [sys.executable, "-m", "rerun"]
    env = {"RERUN_ANALYTICS": "0", "PATH": "/usr/bin:/bin"}
    convert = subprocess.run(rerun + ["mcap", "convert", mcap_path, "-o", rrd_path],
                             capture_output=True, text=True, env=env)
    check = subprocess.run(rerun + ["mcap", "check", mcap_path],
                           capture_output=True, text=True, env=env)
    facts = {"convert_status": convert.returncode, "check_status": check.returncode,
             "check_problems": [l for l in check.stdout.splitlines() if "PROBLEM" in l],
             "columns": {}, "rows": {}}
    rows = {}
    values = {"/tf": [], "/arena/points": [], "/log": [], "/tes/decision": []}
    for c in chunk.RrdReader(rrd_path).stream():
        batch = c.to_record_batch()
        for name in batch.schema.names:
            if ":" in name:
                key = f"{c.entity_path} {name}"
                rows[key] = rows.get(key, 0) + batch.num_rows
        path = c.entity_path
        if path == "/tf" and "Transform3D:translation" in batch.schema.names:
            for t in batch.column("Transform3D:translation").to_pylist():
                values["/tf"].append(t[0])
        if path == "/arena/points" and "Points3D:positions" in batch.schema.names:
            for p, col in zip(batch.column("Points3D:positions").to_pylist(),
                              batch.column("Points3D:colors").to_pylist()):
                values["/arena/points"].append([len(p), len(set(col))])
        if path == "/log" and "TextLog:text" in batch.schema.names:
            values["/log"].extend(batch.column("TextLog:text").to_pylist())
        if path == "/tes/decision":
            for name in batch.schema.names:
                if name.endswith(":message"):
                    for m in batch.column(name).to_pylist():
                        values["/tes/decision"].append(m[0]["latency_us"])
    facts["rows"] = rows
    facts["tf_rows"] = len(values["/tf"])
    facts["arena_points"] = values["/arena/points"]
    facts["log_rows"] = len(values["/log"])
    facts["latencies"] = values["/tes/decision"]
    return facts


def rerun_view():
    """python/tes/rerun_view.py, as a script (it needs nothing of the compiled package)."""
    import os
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.join(here, "..", "..", "..", "python", "tes", "rerun_view.py")


def facts_of_rrd(rrd_path):
    """Each entity's archetype columns and rows, the boxes' sizes and the texts, as
    rerun-sdk's own reader reads them back."""
    import rerun.chunk as chunk
    rows, boxes, texts, said = {}, [], {}, []
    for c in chunk.RrdReader(rrd_path).stream():
        batch = c.to_record_batch()
        for name in batch.schema.names:
            if ":" in name and not name.startswith("rerun."):
                key = f"{c.entity_path} {name}"
                rows[key] = rows.get(key, 0) + batch.num_rows
        if "Boxes3D:half_sizes" in batch.schema.names and c.entity_path.startswith("/arena/arena"):
            for sizes in batch.column("Boxes3D:half_sizes").to_pylist():
                boxes.extend(sizes or [])
        if "TextLog:text" in batch.schema.names:
            texts.setdefault(c.entity_path, []).extend(
                t[0] for t in batch.column("TextLog:text").to_pylist() if t)
        if "Points3D:labels" in batch.schema.names:
            said.extend(t[0] for t in batch.column("Points3D:labels").to_pylist() if t)
    return {"rows": rows, "arena_boxes": len(boxes),
            "largest_box_m": max((2 * max(b) for b in boxes), default=0.0),
            "texts": {k: v[:5] + v[-2:] for k, v in texts.items()},
            "text_rows": {k: len(v) for k, v in texts.items()}, "said": said[:3]}


def facts_of_native(mcap_path, rrd_path):
    run = subprocess.run([sys.executable, rerun_view(), mcap_path, "-o", rrd_path],
                         capture_output=True, text=True, env={"RERUN_ANALYTICS": "0",
                                                              "PATH": "/usr/bin:/bin"})
    if run.returncode != 0:
        raise SystemExit(f"rerun_view.py failed: {run.stderr}")
    return facts_of_rrd(rrd_path)


def facts_of_native_live(addr, rrd_path, seconds):
    # At normal priority: at SCHED_IDLE (its default on this host) the tests running beside
    # it could starve it of its few seconds (what SCHED_IDLE costs the loop is measured by
    # `tes bench latency --rerun`, which runs it as a user does).
    run = subprocess.run([sys.executable, rerun_view(), "--live", addr, "-o", rrd_path,
                          "--seconds", seconds, "--normal-priority"],
                         capture_output=True, text=True,
                         env={"RERUN_ANALYTICS": "0", "PATH": "/usr/bin:/bin"})
    if run.returncode != 0:
        raise SystemExit(f"rerun_view.py --live failed: {run.stderr}")
    return facts_of_rrd(rrd_path)


def facts_of_live(addr, episodes):
    """Connects, checks the advertised channels, subscribes and follows the run; tries bad
    requests; opens a second client that never reads."""
    import base64
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from websockets.sync.client import connect

    def message_class(channel):
        files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
        pool = descriptor_pool.DescriptorPool()
        for f in files.file:
            pool.Add(f)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))

    facts = {"advertised": {}, "received": {}, "statuses": {}, "episodes": [], "tf": 0,
             "arena_entities": 0, "after_bad_requests": 0, "slow_client": None}
    deadline = time.monotonic() + 120
    open_clients = contextlib.ExitStack()

    def client():
        return open_clients.enter_context(
            connect(f"ws://{addr}", subprotocols=["foxglove.sdk.v1"], open_timeout=5,
                    max_size=None))

    with open_clients:
        return follow_live(client, deadline, facts, episodes, message_class)


def follow_live(client, deadline, facts, episodes, message_class):
    ws = client()
    channels = {}
    while len(channels) < 12 and time.monotonic() < deadline:
        m = ws.recv(timeout=10)
        if isinstance(m, str):
            j = json.loads(m)
            if j.get("op") == "advertise":
                for c in j["channels"]:
                    channels[c["id"]] = c
                    facts["advertised"][c["topic"]] = [c["schemaName"], c["encoding"]]
    classes = {i: message_class(c) for i, c in channels.items() if c["encoding"] == "protobuf"}
    by_topic = {c["topic"]: i for i, c in channels.items()}
    subscriptions = {}
    wanted = ["/arena", "/tf", "/tes/episode", "/tes/decision", "/robot"]
    for n, topic in enumerate(wanted):
        subscriptions[n + 1] = by_topic[topic]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": s, "channelId": c} for s, c in subscriptions.items()]}))

    def follow(stop):
        while time.monotonic() < deadline and not stop():
            try:
                m = ws.recv(timeout=10)
            except TimeoutError:
                break
            if isinstance(m, str):
                j = json.loads(m)
                if j.get("op") == "status":
                    said = j.get("message", "")[:60]
                    facts["statuses"][said] = facts["statuses"].get(said, 0) + 1
                continue
            if m[0] != 1:
                continue
            sub, _ = struct.unpack_from("<IQ", m, 1)
            channel = subscriptions.get(sub)
            if channel is None:
                continue
            topic = channels[channel]["topic"]
            facts["received"][topic] = facts["received"].get(topic, 0) + 1
            decoded = classes[channel].FromString(m[13:])
            if topic == "/tes/episode":
                facts["episodes"].append([decoded.episode, decoded.reward])
            elif topic == "/tf":
                facts["tf"] += 1
            elif topic == "/arena":
                facts["arena_entities"] = len(decoded.entities)

    follow(lambda: len(facts["episodes"]) >= 1 and facts["arena_entities"] > 0)
    # A client that subscribes to everything and never reads again.
    slow = client()
    slow_channels = {}
    while len(slow_channels) < 12:
        j = slow.recv(timeout=10)
        if isinstance(j, str) and json.loads(j).get("op") == "advertise":
            for c in json.loads(j)["channels"]:
                slow_channels[c["id"]] = c
    slow.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": 100 + i, "channelId": c} for i, c in enumerate(slow_channels)]}))
    # Bad requests: not JSON, an unknown operation, an unknown channel, a flood of the same
    # subscription.
    ws.send("this is not json")
    ws.send(json.dumps({"op": "launchTheMissiles"}))
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 900, "channelId": 987654}]}))
    for _ in range(200):
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 1, "channelId": by_topic["/arena"]}]}))
    before = len(facts["episodes"])
    follow(lambda: len(facts["episodes"]) >= episodes)
    facts["after_bad_requests"] = len(facts["episodes"]) - before
    facts["slow_client"] = slow.protocol.state.name
    return facts


def facts_of_names(addr):
    """What a client offering only the SDK's name of the protocol, and one offering only its
    published name (Lichtblick's, older Foxglove Studio's), are each given: the subprotocol
    the server answers with, the channels advertised, and messages on /tf once subscribed."""
    from websockets.sync.client import connect

    facts = {}
    for name in ["foxglove.sdk.v1", "foxglove.websocket.v1"]:
        deadline = time.monotonic() + 60
        with connect(f"ws://{addr}", subprotocols=[name], open_timeout=10,
                     max_size=None) as ws:
            channels = {}
            while len(channels) < 12 and time.monotonic() < deadline:
                m = ws.recv(timeout=10)
                if isinstance(m, str) and json.loads(m).get("op") == "advertise":
                    for c in json.loads(m)["channels"]:
                        channels[c["topic"]] = [c["id"], c["schemaName"], c["encoding"]]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": channels["/tf"][0]}]}))
            tf = 0
            while tf < 3 and time.monotonic() < deadline:
                m = ws.recv(timeout=10)
                if isinstance(m, bytes) and m[0] == 1 and struct.unpack_from("<I", m, 1)[0] == 1:
                    tf += 1
            facts[name] = {"subprotocol": ws.subprotocol, "tf": tf,
                           "channels": {t: c[1:] for t, c in channels.items()}}
    return facts


def main():
    mode = sys.argv[1]
    if mode == "mcap":
        facts = facts_of_recording(sys.argv[2])
    elif mode == "rerun":
        facts = facts_of_rerun(sys.argv[2], sys.argv[3])
    elif mode == "live":
        facts = facts_of_live(sys.argv[2], int(sys.argv[3]))
    elif mode == "native":
        facts = facts_of_native(sys.argv[2], sys.argv[3])
    elif mode == "native-live":
        facts = facts_of_native_live(sys.argv[2], sys.argv[3], sys.argv[4])
    elif mode == "names":
        facts = facts_of_names(sys.argv[2])
    else:
        raise SystemExit(__doc__)
    print(json.dumps(facts))


if __name__ == "__main__":
    main()
