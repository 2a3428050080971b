"""An independent NXT client for the simulated brick: nxt-python's devfile backend.

Usage: python3 nxt_client.py PATH   (PATH: the pseudo-terminal `tes-bridge brick --pty PATH` links)

Exits non-zero with a message on the first failed check. Driven by tests/it/nxt_python.rs.
"""

import sys
import time

import nxt.locator
import nxt.motor
from nxt.motor import Mode, Port, RegulationMode, RunState


def check(cond, what):
    if not cond:
        print(f"FAILED: {what}", flush=True)
        sys.exit(1)
    print(f"ok: {what}", flush=True)


def wait_idle(brick, port, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        state = brick.get_output_state(port)
        if state[5] == RunState.IDLE:
            return state
        time.sleep(0.02)
    raise AssertionError(f"port {port} still running after {timeout} s")


def main(path):
    # Discovery by name makes nxt-python ask GETDEVICEINFO, as it does for a real brick.
    brick = nxt.locator.find(backends=["devfile"], filename=path, name="NXT")
    prot, fw = brick.get_firmware_version()
    check(prot == (1, 124) and fw == (1, 28), f"firmware version {fw}, protocol {prot}")
    name, host, _, _ = brick.get_device_info()
    check(name == "NXT" and host.startswith("00:16:53:"), f"device info {name} {host}")
    mv = brick.get_battery_level()
    check(6000 <= mv <= 10000, f"battery {mv} mV")
    check(brick.keep_alive() == 600000, "keep-alive sleep timeout")
    brick.play_tone(440, 50)

    brick.reset_motor_position(Port.B, False)
    brick.reset_motor_position(Port.B, True)
    regulated = Mode.ON | Mode.BRAKE | Mode.REGULATED
    brick.set_output_state(Port.B, 75, regulated, RegulationMode.SPEED, 0, RunState.RUNNING, 360)
    state = wait_idle(brick, Port.B)
    tacho = state[7]
    check(360 <= tacho <= 390, f"tacho count after a 360 deg limit: {tacho}")
    check(state[1] == 75 and state[6] == 360, f"power and limit echoed: {state[1]}, {state[6]}")
    # The next limit counts from the previous target: the overshoot is absorbed.
    brick.set_output_state(Port.B, 75, regulated, RegulationMode.SPEED, 0, RunState.RUNNING, 360)
    tacho2 = wait_idle(brick, Port.B)[7]
    check(720 <= tacho2 <= 750, f"tacho count after a second 360 deg limit: {tacho2}")

    # The high-level API: Motor.turn polls GETOUTPUTSTATE and brakes at the end.
    motor = brick.get_motor(Port.C)
    motor.turn(-75, 180)
    tacho_c = motor.get_tacho().tacho_count
    check(tacho_c <= -150, f"Motor.turn(-75, 180) moved port C to {tacho_c}")
    check(brick.get_output_state(Port.A)[7] == 0, "port A never moved")

    # Error statuses, through the raw socket.
    brick._sock.send(bytes([0x00, 0x06, 0x05]))
    reply = brick._sock.recv()
    check(reply[:3] == bytes([0x02, 0x06, 0xC0]) and len(reply) == 25, f"bad port reply {reply.hex()}")
    brick._sock.send(bytes([0x00, 0x7E]))
    reply = brick._sock.recv()
    check(reply == bytes([0x02, 0x7E, 0xBE]), f"unknown opcode reply {reply.hex()}")

    brick.close()
    print("nxt-python client: all checks passed", flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__)
        sys.exit(2)
    main(sys.argv[1])
