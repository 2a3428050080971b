"""An independent Zenoh client (PyPI's eclipse-zenoh) that tries to join a TES group.

    python3 zenoh_stranger.py ENDPOINT GROUP SECONDS [--ca CA] [--cert CERT --key KEY]
        [--payload HEX] [--no-token] [--sender own|controller|none|ID]

It connects to ENDPOINT as a peer with whatever credentials it is given (none, another
authority's, a member's), announces itself as the group's controller (unless --no-token), and
publishes on the group's command key for SECONDS: PAYLOAD's bytes (64 zero bytes by default),
each with the sender's id the link's own forwarding attaches — its own session's, the
controller's it reads off the group's member tokens or is given (a forgery), or none. It prints one JSON
object: how many peers it reached (a refused connection reaches none), how many commands it
sent, its session id and the controller's id it found.
"""

import argparse
import json
import time

import zenoh


def controller_zid(session, group):
    """The session id in the group's controller token, if one is seen within 5 s."""
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        for reply in session.liveliness().get(f"{group}/member/controller/*", timeout=1.0):
            if reply.ok is not None:
                return str(reply.ok.key_expr).rsplit("/", 1)[-1]
        time.sleep(0.1)
    return None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("endpoint")
    parser.add_argument("group")
    parser.add_argument("seconds", type=float)
    parser.add_argument("--ca")
    parser.add_argument("--cert")
    parser.add_argument("--key")
    parser.add_argument("--payload", default="00" * 64)
    parser.add_argument("--no-token", action="store_true")
    parser.add_argument("--sender", default="own", help="own, controller, none, or an id")
    args = parser.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    # PyPI's client makes a shared-memory segment per session (`/dev/shm/*.zenoh`), which a
    # killed stranger leaves behind; the link does not use shared memory, so neither does it.
    conf.insert_json5("transport/shared_memory/enabled", "false")
    tls = "transport/link/tls/"
    if args.ca:
        conf.insert_json5(tls + "root_ca_certificate", json.dumps(args.ca))
        conf.insert_json5(tls + "verify_name_on_connect", "false")
    if args.cert:
        conf.insert_json5(tls + "connect_certificate", json.dumps(args.cert))
        conf.insert_json5(tls + "connect_private_key", json.dumps(args.key))
        conf.insert_json5(tls + "enable_mtls", "true")

    session = zenoh.open(conf)
    zid = str(session.zid())
    token = None
    if not args.no_token:
        token = session.liveliness().declare_token(f"{args.group}/member/controller/{zid}")
    found = controller_zid(session, args.group) if args.sender == "controller" else None
    sender = {"own": zid, "controller": found, "none": None}.get(args.sender, args.sender)
    payload = bytes.fromhex(args.payload)
    publisher = session.declare_publisher(f"{args.group}/command")
    sent, peers = 0, set()
    deadline = time.monotonic() + args.seconds
    while time.monotonic() < deadline:
        if sender is None:
            publisher.put(payload)
        else:
            publisher.put(payload, attachment=sender.encode())
        sent += 1
        peers.update(str(p) for p in session.info.peers_zid())
        time.sleep(0.05)
    if token is not None:
        token.undeclare()
    session.close()
    print(json.dumps({"zid": zid, "peers": len(peers), "sent": sent, "controller": found}))


if __name__ == "__main__":
    main()
