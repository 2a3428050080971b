"""An independent Zenoh client (PyPI's eclipse-zenoh) that tries to join a TES group.

    python3 zenoh_stranger.py ENDPOINT GROUP SECONDS [--ca CA] [--cert CERT --key KEY]

It connects to ENDPOINT as a peer with whatever credentials it is given (none, another
authority's, a member's), announces itself as the group's controller, and publishes on the
group's command key for SECONDS. It prints one JSON object: how many peers it reached (a
refused connection reaches none) and how many commands it sent.
"""

import argparse
import json
import time

import zenoh


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("endpoint")
    parser.add_argument("group")
    parser.add_argument("seconds", type=float)
    parser.add_argument("--ca")
    parser.add_argument("--cert")
    parser.add_argument("--key")
    args = parser.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
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
    token = session.liveliness().declare_token(f"{args.group}/member/controller/{zid}")
    publisher = session.declare_publisher(f"{args.group}/command")
    sent, peers = 0, set()
    deadline = time.monotonic() + args.seconds
    while time.monotonic() < deadline:
        publisher.put(bytes(64))
        sent += 1
        peers.update(str(p) for p in session.info.peers_zid())
        time.sleep(0.05)
    token.undeclare()
    session.close()
    print(json.dumps({"zid": zid, "peers": len(peers), "sent": sent}))


if __name__ == "__main__":
    main()
