"""A TES run drawn natively in Rerun: the arena's cells, marks, ball and walls as shapes to
scale, the robot's body moving (where the world has it, and a faint outline where the
controller believes it is), the episode's path as a line, each decision as text, and the
reward and latency as plots.

A recording (``tes launch --record run.mcap``, or a grid run's ``--draw``) holds the run in
Foxglove's schemas; this reads its drawn channels and logs them through rerun-sdk's own
archetypes (``Boxes3D``, ``Cylinders3D``, ``Ellipsoids3D``, ``LineStrips3D``, ``Arrows3D``,
``Transform3D``, ``TextLog``, ``Scalars``), which Rerun's MCAP importer does not do for
Foxglove's scene entities. Live, it follows a group's Foxglove WebSocket server
(``tes launch --foxglove``) and logs the same way to a Rerun viewer or an ``.rrd``::

    python3 -m pip install 'rerun-sdk==0.41.*' 'mcap==1.*' 'websockets==17.*'
    python3 python/tes/rerun_view.py run.mcap -o run.rrd     # then: rerun run.rrd
    python3 python/tes/rerun_view.py --live 127.0.0.1:8765 --spawn
    python3 python/tes/rerun_view.py --live 127.0.0.1:8765 -o live.rrd --seconds 30

It needs nothing of the compiled ``tes`` package, so it runs as a script from a checkout as
well as ``python -m tes.rerun_view`` once the package is installed.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import struct
import sys
import time
from typing import Any, Callable, Iterable

#: Where each part of the run goes in Rerun's entity tree.
ARENA = "arena"
ROBOT = "arena/robot"
BELIEF = "arena/belief"
PATH = "arena/path"
SAID = "arena/robot/said"
DECISIONS = "decisions"
EPISODES = "episodes"
LOG = "log"
LATENCY = "plots/latency_us"
REWARD = "plots/reward"

#: The Foxglove frames the recording names, as entity paths: Rerun places a child entity by
#: its parent's transform, so the frame tree becomes the entity tree.
FRAMES = {"arena": ARENA, "robot": ROBOT, "belief": BELIEF}

#: The drawn channels this reads; the rest of a recording (``/tes/observation``, …) is the
#: data underneath, not a drawing.
TOPICS = ("/arena", "/tf", "/tf/belief", "/robot", "/log", "/tes/decision", "/tes/episode")

#: The timeline every message is put on: its wall-clock time, as Foxglove shows it.
TIMELINE = "time"

#: Live, how often the gathered rows go to Rerun and the growing drawings (the path, the text
#: over the robot) are redrawn: 20 times a second, about a display's pace. Every transform,
#: decision and latency is kept; only a path or text a newer one replaced within the same
#: 50 ms is not drawn. A client that does less per message takes less CPU from the group.
LIVE_FLUSH_NS = 50_000_000

#: From a recording: rows go to Rerun once a second of the run, and every drawing is kept.
FILE_FLUSH_NS = 1_000_000_000


def message_classes(schema_name: str, descriptor_set: bytes) -> Any:
    """The Protobuf class of ``schema_name`` from the file descriptor set a channel carries
    (a recording's schema record, a live server's ``advertise``)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def _rgba(c: Any) -> list[int]:
    return [round(255 * max(0.0, min(1.0, v))) for v in (c.r, c.g, c.b, c.a)]


def _xyz(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def _xyzw(q: Any) -> list[float]:
    return [q.x, q.y, q.z, q.w]


def _pose(rr: Any, pose: Any) -> tuple[list[float], Any]:
    return _xyz(pose.position), rr.Quaternion(xyzw=_xyzw(pose.orientation))


class RunLogger:
    """Turns the drawn channels' messages into Rerun's archetypes, in the order of the run.

    The many small rows (each transform, decision and latency) are gathered and sent as
    columns (``rr.send_columns``) every ``flush_ns`` of the run, which costs a fraction of a
    ``rr.log`` call each; with ``latest_only`` a drawing that grows (the path, the text over
    the robot) is drawn as it stands at each send, not at every message. Call ``flush`` at
    the end (and live, when no message came for a while)."""

    def __init__(self, rr: Any, flush_ns: int = FILE_FLUSH_NS, latest_only: bool = False) -> None:
        self.rr = rr
        self.static_done: set[str] = set()
        self.flush_ns = flush_ns
        self.latest_only = latest_only
        self.now_ns = 0
        self.flushed_ns: int | None = None
        #: entity → (archetype, times, columns), sent at the next flush.
        self.rows: dict[str, tuple[Any, list[int], dict[str, list[Any]]]] = {}
        #: entity → (time, drawing) of a growing drawing, drawn at the next flush.
        self.latest: dict[str, tuple[int, Callable[[], None]]] = {}
        rr.log(ARENA, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def put(self, topic: str, time_ns: int, m: Any) -> None:
        """Takes message ``m`` of ``topic`` at ``time_ns`` (wall clock, ns)."""
        self.now_ns = time_ns
        if self.flushed_ns is None:
            self.flushed_ns = time_ns
        handler: Callable[[Any], None] | None = {
            "/arena": self.arena,
            "/tf": self.transform,
            "/tf/belief": self.transform,
            "/robot": self.robot,
            "/log": self.log_line,
            "/tes/decision": self.decision,
            "/tes/episode": self.episode,
        }.get(topic)
        if handler is not None:
            handler(m)
        if time_ns - self.flushed_ns >= self.flush_ns:
            self.flush()

    def at_now(self) -> None:
        """Puts the next ``rr.log`` at the message's time."""
        self.rr.set_time(TIMELINE, timestamp=self.now_ns * 1e-9)

    def row(self, entity: str, archetype: Any, **fields: Any) -> None:
        """One row of ``archetype`` for ``entity`` at the message's time, sent at the next
        flush."""
        _, times, columns = self.rows.setdefault(entity, (archetype, [], {}))
        times.append(self.now_ns)
        for name, value in fields.items():
            columns.setdefault(name, []).append(value)

    def growing(self, entity: str, draw: Callable[[], None]) -> None:
        """A drawing that replaces the last one of ``entity``: drawn now, or (``latest_only``)
        as it stands at the next flush."""
        if self.latest_only:
            self.latest[entity] = (self.now_ns, draw)
        else:
            self.at_now()
            draw()

    def flush(self) -> None:
        """Sends the gathered rows as columns, and draws each growing drawing's latest."""
        import numpy as np

        rr = self.rr
        for entity, (archetype, times, columns) in self.rows.items():
            stamps = np.array(times, dtype="datetime64[ns]")
            rr.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, timestamp=stamps)],
                            columns=archetype.columns(**columns))
        self.rows.clear()
        for time_ns, draw in self.latest.values():
            rr.set_time(TIMELINE, timestamp=time_ns * 1e-9)
            draw()
        self.latest.clear()
        self.flushed_ns = self.now_ns

    def arena(self, update: Any) -> None:
        """The world, once: its cubes (floor, cells, death spots, walls) as boxes, its marks
        as flat cylinders, the ball as a sphere, the grid as lines."""
        self.at_now()
        for e in update.entities:
            self.shapes(f"{ARENA}/{e.id}", e, static=True)

    def shapes(self, path: str, e: Any, static: bool) -> None:
        """A scene entity's primitives under ``path``, one archetype per kind."""
        rr = self.rr
        if e.cubes:
            rr.log(f"{path}/boxes", rr.Boxes3D(
                centers=[_xyz(c.pose.position) for c in e.cubes],
                half_sizes=[[c.size.x / 2, c.size.y / 2, c.size.z / 2] for c in e.cubes],
                quaternions=[rr.Quaternion(xyzw=_xyzw(c.pose.orientation)) for c in e.cubes],
                colors=[_rgba(c.color) for c in e.cubes],
                fill_mode="solid"), static=static)
        if e.cylinders:
            rr.log(f"{path}/cylinders", rr.Cylinders3D(
                centers=[_xyz(c.pose.position) for c in e.cylinders],
                lengths=[c.size.z for c in e.cylinders],
                radii=[c.size.x / 2 for c in e.cylinders],
                colors=[_rgba(c.color) for c in e.cylinders],
                fill_mode="solid"), static=static)
        if e.spheres:
            rr.log(f"{path}/spheres", rr.Ellipsoids3D(
                centers=[_xyz(s.pose.position) for s in e.spheres],
                half_sizes=[[s.size.x / 2, s.size.y / 2, s.size.z / 2] for s in e.spheres],
                colors=[_rgba(s.color) for s in e.spheres],
                fill_mode="solid"), static=static)
        for i, line in enumerate(e.lines):
            points = [_xyz(p) for p in line.points]
            # Foxglove's line types: 0 a strip, 1 a loop, 2 a list of separate segments.
            if line.type == 2:
                strips = [points[k:k + 2] for k in range(0, len(points) - 1, 2)]
            else:
                strips = [points + points[:1] if line.type == 1 else points]
            rr.log(f"{path}/lines{i}", rr.LineStrips3D(
                strips, colors=[_rgba(line.color)], radii=rr.Radius.ui_points(line.thickness)),
                static=static)
        if e.arrows:
            rr.log(f"{path}/arrows", rr.Arrows3D(
                origins=[_xyz(a.pose.position) for a in e.arrows],
                vectors=[[a.shaft_length + a.head_length, 0.0, 0.0] for a in e.arrows],
                colors=[_rgba(a.color) for a in e.arrows]), static=static)

    def transform(self, t: Any) -> None:
        """``parent → child`` as the child entity's transform."""
        child = FRAMES.get(t.child_frame_id, f"{ARENA}/{t.child_frame_id}")
        self.row(child, self.rr.Transform3D, translation=_xyz(t.translation),
                 quaternion=_xyzw(t.rotation))

    def robot(self, update: Any) -> None:
        """The robot's entities: its body and the belief's outline (drawn once, in their
        frames), its episode's path, the text over it."""
        rr = self.rr
        for e in update.entities:
            if e.id == "path":
                self.growing(PATH, lambda e=e: rr.log(PATH, rr.LineStrips3D(
                    [[_xyz(p) for line in e.lines for p in line.points]],
                    colors=[[245, 197, 24, 255]], radii=rr.Radius.ui_points(3.0))))
            elif e.id == "decision" and e.texts:
                text = e.texts[0]
                self.growing(SAID, lambda text=text: rr.log(SAID, rr.Points3D(
                    [_xyz(text.pose.position)], labels=[text.text], radii=0.005,
                    colors=[[255, 255, 255, 255]], show_labels=True)))
            elif e.frame_id in FRAMES and e.id not in self.static_done:
                self.static_done.add(e.id)
                self.at_now()
                self.shapes(f"{FRAMES[e.frame_id]}/{e.id}", e, static=True)

    def log_line(self, line: Any) -> None:
        levels = {1: "DEBUG", 2: "INFO", 3: "WARN", 4: "ERROR", 5: "CRITICAL"}
        self.row(LOG, self.rr.TextLog, text=f"{line.name}: {line.message}",
                 level=levels.get(line.level, "INFO"))

    def decision(self, d: Any) -> None:
        self.row(DECISIONS, self.rr.TextLog,
                 text=f"episode {d.episode} step {d.step}: {d.action_name} "
                      f"({d.latency_us:.1f} µs)")
        self.row(LATENCY, self.rr.Scalars, scalars=d.latency_us)

    def episode(self, e: Any) -> None:
        self.row(EPISODES, self.rr.TextLog,
                 text=f"episode {e.episode}: {e.outcome}, reward {e.reward:.2f} in "
                      f"{e.actions} actions")
        self.row(REWARD, self.rr.Scalars, scalars=e.reward)


def blueprint() -> Any:
    """The arena in 3D beside the plots and the texts."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial3DView(origin=ARENA, name="arena"),
        rrb.Vertical(
            rrb.TimeSeriesView(origin=REWARD, name="episode reward"),
            rrb.TimeSeriesView(origin=LATENCY, name="decision latency (µs)"),
            rrb.TextLogView(origin=DECISIONS, name="decisions"),
            rrb.TextLogView(contents=[f"/{LOG}", f"/{EPISODES}"], name="log and episodes")),
        column_shares=[3, 2]))


def recorded_messages(path: str) -> Iterable[tuple[str, int, Any]]:
    """The drawn messages of the MCAP file ``path``, decoded, in file order."""
    from mcap.reader import make_reader

    classes: dict[int, Any] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(topics=list(TOPICS)):
            if channel.message_encoding != "protobuf" or schema is None:
                continue
            if channel.id not in classes:
                classes[channel.id] = message_classes(schema.name, schema.data)
            yield channel.topic, message.log_time, classes[channel.id].FromString(message.data)


def convert(mcap_path: str, rrd_path: str, recording_id: str | None = None) -> int:
    """Writes the run of the recording ``mcap_path`` as Rerun's ``rrd_path``; returns the
    number of messages drawn."""
    import rerun as rr

    rec = rr.RecordingStream("tes", recording_id=recording_id or mcap_path)
    with rec:
        rec.save(rrd_path, default_blueprint=blueprint())
        drawn = 0
        logger = RunLogger(rr)
        for topic, time_ns, message in recorded_messages(mcap_path):
            logger.put(topic, time_ns, message)
            drawn += 1
        logger.flush()
        rec.flush()
    return drawn


def live_messages(addr: str, seconds: float | None) -> Iterable[tuple[str, int, Any] | None]:
    """The drawn messages a live group's Foxglove WebSocket server at ``addr`` sends, decoded,
    for ``seconds`` (or until the server closes); ``None`` when none came for a while."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    deadline = None if seconds is None else time.monotonic() + seconds
    with connect(f"ws://{addr}", subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        channels: dict[int, tuple[str, Any]] = {}
        subscribed: dict[int, tuple[str, Any]] = {}
        while deadline is None or time.monotonic() < deadline:
            try:
                frame = ws.recv(timeout=LIVE_FLUSH_NS * 1e-9)
            except TimeoutError:
                yield None
                continue
            except ConnectionClosed:
                return  # the group ended: its server closed the connection
            if isinstance(frame, str):
                new = _advertised(json.loads(frame), channels)
                if new:
                    subs = []
                    for channel_id in new:
                        sub_id = len(subscribed) + 1
                        subscribed[sub_id] = channels[channel_id]
                        subs.append({"id": sub_id, "channelId": channel_id})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif frame[:1] == b"\x01":
                sub_id, stamp = struct.unpack_from("<IQ", frame, 1)
                if sub_id in subscribed:
                    topic, cls = subscribed[sub_id]
                    yield topic, stamp, cls.FromString(frame[13:])


def _advertised(op: dict, channels: dict[int, tuple[str, Any]]) -> list[int]:
    """Takes an ``advertise`` operation's drawn Protobuf channels into ``channels``; returns
    the new ones' ids."""
    if op.get("op") != "advertise":
        return []
    new = []
    for c in op.get("channels", []):
        if c.get("topic") in TOPICS and c.get("encoding") == "protobuf":
            schema = base64.b64decode(c["schema"])
            channels[c["id"]] = (c["topic"], message_classes(c["schemaName"], schema))
            new.append(c["id"])
    return new


def _give_way(addr: str) -> None:
    """Keeps this process (and every thread it starts from here on: rerun-sdk's, the
    socket's) out of the way of a group it follows on the group's own host (``addr`` on
    loopback): at ``SCHED_IDLE``, the lowest priority Linux has, which the group's threads
    preempt at once; it still gets every idle moment of the CPUs. (Where Linux's scheduling
    calls are missing, or the group is on another host, it runs as started.)"""
    host = addr.rsplit(":", 1)[0].strip("[]")
    if host not in ("127.0.0.1", "localhost", "::1"):
        return
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        pass


def follow(addr: str, rrd_path: str | None, spawn: bool, seconds: float | None,
           give_way: bool = True) -> int:
    """Logs a live group's run to a Rerun viewer (``spawn``) and/or ``rrd_path``; returns the
    number of messages drawn. Unless ``give_way`` is false it runs at ``SCHED_IDLE`` when the
    group is on this host (:func:`_give_way`)."""
    if give_way:
        _give_way(addr)
    import rerun as rr

    rr.init("tes", recording_id=f"live {addr} {time.time_ns()}")
    if spawn:
        rr.spawn(default_blueprint=blueprint())
    if rrd_path:
        rr.save(rrd_path, default_blueprint=blueprint())
    logger, drawn = RunLogger(rr, flush_ns=LIVE_FLUSH_NS, latest_only=True), 0
    try:
        for message in live_messages(addr, seconds):
            if message is None:
                logger.flush()
                continue
            logger.put(*message)
            drawn += 1
    except KeyboardInterrupt:
        pass
    logger.flush()
    rr.disconnect()
    return drawn


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="rerun_view", description=__doc__.split("\n\n")[0])
    parser.add_argument("mcap", nargs="?", help="a TES recording (.mcap) to convert")
    parser.add_argument("-o", "--output", help="the .rrd to write")
    parser.add_argument("--live", metavar="HOST:PORT",
                        help="follow a group's live Foxglove server instead of a file")
    parser.add_argument("--spawn", action="store_true", help="live: show it in a Rerun viewer")
    parser.add_argument("--seconds", type=float, help="live: stop after this long")
    parser.add_argument("--normal-priority", action="store_true",
                        help="live: keep normal priority (following a group on this host it "
                             "runs at SCHED_IDLE, so as never to hold the group up; a busy "
                             "host can then starve it)")
    args = parser.parse_args(argv)
    if args.live:
        if not (args.output or args.spawn):
            parser.error("--live needs -o FILE.rrd or --spawn")
        drawn = follow(args.live, args.output, args.spawn, args.seconds,
                       give_way=not args.normal_priority)
    elif args.mcap and args.output:
        drawn = convert(args.mcap, args.output)
    else:
        parser.error("give a recording and -o FILE.rrd, or --live HOST:PORT")
    print(f"drew {drawn} messages", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
