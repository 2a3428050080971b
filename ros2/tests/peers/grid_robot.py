"""A ROS 2 robot on Eclipse Cyclone DDS that plays a grid task (a small MDP) against TES.

    python grid_robot.py TASK.json --domain D --episodes N --seed S --out RESULT.json
                         [--timeout SECONDS] [--send-malformed]

TASK.json describes the task: `width`, `height`, `n_states` (width*height + 1, the last an
unreachable "out of the area" state), `n_actions`, `n_effects`, `n_features`, and per state
`next_state` (n_effects state indices), `reward` (for entering it), `terminal`, `features`
(the indices that are on) and `effect_probs` (per action, n_effects probabilities); `starts`
(an episode starts at one drawn uniformly) and `step_cap` (an episode is cut after that many
actions).

The robot is a ROS 2 node on its own (stdlib, `cyclonedds` and `ros2_types`, nothing from
TES), with ROS 2's DDS names (`rt/<topic>`) and types:

- `/tes/world/map`, std_msgs/Float32MultiArray, reliable, transient-local, keep-last 1:
  published once at start; dims [("states", S, S*C), ("columns", C, C)], C = 2 + E + F,
  row s = [reward, terminal 0/1, next_state[0..E], feature bits[0..F]].
- `/tes/world/step`, std_msgs/Float64MultiArray, reliable, volatile, keep-last 64: one per
  step, data = [episode, step, answers, state, effect, reward, flags, f_0 .. f_{F-1}],
  dims [("step", 7+F, 7+F)]; flags 1 = terminal, 4 = cut at the step cap.
- `/tes/world/action`, std_msgs/UInt32MultiArray, reliable, volatile, keep-last 64: TES's
  answers, data = [seq, action, episode, step].

Prints `ready` once its participant, readers and writers exist, then plays N episodes with
`random.Random(SEED)` drawing starts and effects. While it waits for an answer it republishes
the step every 0.5 s (discovery takes seconds, and what is written before a reader matches is
lost); TES takes each step once and answers a repeat again. With every episode done it writes RESULT.json (per episode its
reward, actions and how it ended; the count of malformed actions), prints `done` and exits 0.
With no answer to a step within the timeout (60 s unless told) it exits with status 2."""

import argparse
import json
import random
import sys
import time

from cyclonedds.core import (InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState,
                             WaitSet)
from cyclonedds.domain import DomainParticipant
from cyclonedds.internal import InvalidSample
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

import ros2_types as t

MAP_TOPIC = "/tes/world/map"
STEP_TOPIC = "/tes/world/step"
ACTION_TOPIC = "/tes/world/action"

# The step message's flags.
TERMINAL = 1
CUT = 4

# How often a step with no answer yet goes out again.
REPUBLISH_S = 0.5


class NoAnswer(Exception):
    """No action answered a step in time."""


def dds_name(topic):
    # ROS 2 maps topic `/a/b` to the DDS topic `rt/a/b`.
    return "rt" + topic


def qos(latched, depth):
    return Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
    )


def load_task(path):
    """The task from its JSON, its shape checked so a bad file fails here, not mid-episode."""
    with open(path) as f:
        task = json.load(f)
    s, e, a, n_f = task["n_states"], task["n_effects"], task["n_actions"], task["n_features"]
    problems = []
    if s != task["width"] * task["height"] + 1:
        problems.append(f"n_states {s} is not width*height + 1")
    for key in ("next_state", "reward", "terminal", "features", "effect_probs"):
        if len(task[key]) != s:
            problems.append(f"{key} has {len(task[key])} states, not {s}")
    for i, row in enumerate(task["next_state"]):
        if len(row) != e or not all(0 <= x < s for x in row):
            problems.append(f"next_state[{i}] is not {e} state indices")
    for i, on in enumerate(task["features"]):
        if not all(0 <= x < n_f for x in on):
            problems.append(f"features[{i}] has an index outside 0..{n_f}")
    for i, per_action in enumerate(task["effect_probs"]):
        if len(per_action) != a or any(len(p) != e or abs(sum(p) - 1.0) > 1e-6 for p in per_action):
            problems.append(f"effect_probs[{i}] is not {a} distributions over {e} effects")
    if not task["starts"] or not all(0 <= x < s for x in task["starts"]):
        problems.append("starts is empty or holds a non-state")
    if task["step_cap"] < 1:
        problems.append("step_cap is below 1")
    if problems:
        sys.exit(f"grid_robot: {path} is not a valid task: " + "; ".join(problems[:5]))
    return task


def feature_bits(task, state):
    """The state's features as F values 0.0/1.0, as the map and the steps carry them."""
    bits = [0.0] * task["n_features"]
    for i in task["features"][state]:
        bits[i] = 1.0
    return bits


def world_map(task):
    """The task as one S x C table, row s = [reward, terminal, next states, feature bits]."""
    s, e, n_f = task["n_states"], task["n_effects"], task["n_features"]
    c = 2 + e + n_f
    data = []
    for state in range(s):
        data.append(float(task["reward"][state]))
        data.append(1.0 if task["terminal"][state] else 0.0)
        data.extend(float(x) for x in task["next_state"][state])
        data.extend(feature_bits(task, state))
    layout = t.MultiArrayLayout(
        dim=[t.MultiArrayDimension("states", s, s * c), t.MultiArrayDimension("columns", c, c)],
        data_offset=0,
    )
    return t.Float32MultiArray(layout=layout, data=data)


def step_message(task, episode, step, answers, state, effect, reward, flags):
    """[episode, step, answers, state, effect, reward, flags, f_0 .. f_{F-1}]: float64s hold
    every index and seq exactly."""
    data = [float(episode), float(step), float(answers), float(state), float(effect),
            float(reward), float(flags)] + feature_bits(task, state)
    n = len(data)
    layout = t.MultiArrayLayout(dim=[t.MultiArrayDimension("step", n, n)], data_offset=0)
    return t.Float64MultiArray(layout=layout, data=data)


def flags_of(task, state, step):
    # Reaching a terminal state ends the episode before the cap does.
    if task["terminal"][state]:
        return TERMINAL
    if step >= task["step_cap"]:
        return CUT
    return 0


class Robot:
    def __init__(self, task, domain, timeout, send_malformed=False):
        self.task = task
        # Once, after the first answer (discovery is done then, so it arrives): a step of
        # the wrong size, which TES must count and drop without losing the exchange.
        self.send_malformed = send_malformed
        self.timeout = timeout
        self.participant = DomainParticipant(domain)
        p = self.participant
        self.map_writer = DataWriter(p, Topic(p, dds_name(MAP_TOPIC), t.Float32MultiArray),
                                     qos=qos(True, 1))
        self.step_writer = DataWriter(p, Topic(p, dds_name(STEP_TOPIC), t.Float64MultiArray),
                                      qos=qos(False, 64))
        self.actions = DataReader(p, Topic(p, dds_name(ACTION_TOPIC), t.UInt32MultiArray),
                                  qos=qos(False, 64))
        # Wakes the wait for an answer as soon as an action arrives, rather than polling.
        self.waitset = WaitSet(p)
        self.waitset.attach(
            ReadCondition(self.actions, SampleState.Any | ViewState.Any | InstanceState.Any))
        self.last_seq = None
        self.last_step = None
        self.malformed = 0

    def answer(self, episode, step):
        """Waits for TES's action answering step `step` of episode `episode`: its (seq,
        action). Repeats of the step go out every REPUBLISH_S meanwhile; other actions are
        dropped, the malformed ones counted."""
        started = time.monotonic()
        next_republish = started + REPUBLISH_S
        while True:
            for m in self.actions.take(N=64):
                if isinstance(m, InvalidSample):
                    # An instance's state change (a writer gone), no data.
                    continue
                if len(m.data) != 4 or m.data[1] >= self.task["n_actions"]:
                    self.malformed += 1
                    continue
                seq, action, for_episode, for_step = m.data
                if (for_episode, for_step) != (episode, step):
                    # An answer to an earlier step, resent because a repeat reached TES.
                    continue
                if self.last_seq is not None and seq <= self.last_seq:
                    # TES's seqs only grow: not newer than the last acted on is a stale one.
                    continue
                self.last_seq = seq
                return seq, action
            now = time.monotonic()
            if now - started > self.timeout:
                raise NoAnswer(f"no action answered episode {episode} step {step} "
                               f"within {self.timeout:g} s")
            if now >= next_republish:
                self.step_writer.write(self.last_step)
                next_republish = now + REPUBLISH_S
            wait = min(next_republish, started + self.timeout) - time.monotonic()
            self.waitset.wait(duration(seconds=max(wait, 0.0)))

    def publish(self, *fields):
        # Kept for the repeats while no answer comes.
        self.last_step = step_message(self.task, *fields)
        self.step_writer.write(self.last_step)

    def play(self, episodes, rng):
        task = self.task
        results = []
        for episode in range(episodes):
            state = rng.choice(task["starts"])
            step, total = 0, 0.0
            # The same rule as after an action: a terminal start ends its episode at once.
            flags = flags_of(task, state, step)
            self.publish(episode, step, 0, state, -1, 0.0, flags)
            while flags == 0:
                seq, action = self.answer(episode, step)
                if self.send_malformed:
                    self.send_malformed = False
                    self.step_writer.write(t.Float64MultiArray(
                        layout=t.MultiArrayLayout(dim=[], data_offset=0), data=[1.0, 2.0, 3.0]))
                probs = task["effect_probs"][state][action]
                effect = rng.choices(range(len(probs)), weights=probs)[0]
                state = task["next_state"][state][effect]
                step += 1
                reward = float(task["reward"][state])
                total += reward
                flags = flags_of(task, state, step)
                self.publish(episode, step, seq, state, effect, reward, flags)
            results.append({"reward": total, "actions": step,
                            "ended": "terminal" if flags == TERMINAL else "cut"})
        return results


def main():
    parser = argparse.ArgumentParser(description="A ROS 2 robot playing a grid task against TES.")
    parser.add_argument("task")
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--episodes", type=int, required=True)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--timeout", type=float, default=60.0)
    parser.add_argument("--send-malformed", action="store_true",
                        help="send one step of the wrong size after the first answer")
    args = parser.parse_args()

    task = load_task(args.task)
    robot = Robot(task, args.domain, args.timeout, args.send_malformed)
    # Latched: the writer keeps it for readers that match later.
    robot.map_writer.write(world_map(task))
    print("ready", flush=True)

    try:
        episodes = robot.play(args.episodes, random.Random(args.seed))
    except NoAnswer as e:
        print(f"grid_robot: {e}", file=sys.stderr, flush=True)
        sys.exit(2)
    with open(args.out, "w") as f:
        json.dump({"episodes": episodes, "malformed_actions": robot.malformed}, f)
    print("done", flush=True)
    # The last step is on its way (no answer acknowledges it), and a reader may still be
    # fetching the map: both writers stay a moment before the participant goes.
    try:
        robot.step_writer.wait_for_acks(duration(seconds=1))
    except Exception:  # noqa: BLE001 - TES may have gone with its episodes done: no acks come
        pass
    time.sleep(1.0)


if __name__ == "__main__":
    main()
