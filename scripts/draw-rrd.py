"""Draws a TES run to PNG from the .rrd Rerun converted it to: the arena's points in the
colours Rerun decoded and the robot's positions from its transforms, the path broken where a
new episode starts. What it draws is what Rerun holds, read back through rerun-sdk's own reader.

    python3 -m pip install 'rerun-sdk==0.41.*' matplotlib
    rerun mcap convert run.mcap -o run.rrd
    python3 scripts/draw-rrd.py run.rrd arena.png
"""
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import rerun.chunk as chunk  # noqa: E402


def read(rrd):
    points, colours, robot = [], [], []
    for c in chunk.RrdReader(rrd).stream():
        batch = c.to_record_batch()
        names = batch.schema.names
        if c.entity_path == "/arena/points" and "Points3D:positions" in names:
            for ps, cs in zip(batch.column("Points3D:positions").to_pylist(),
                              batch.column("Points3D:colors").to_pylist()):
                points.extend(ps)
                colours.extend(cs)
        if c.entity_path == "/tf" and "Transform3D:translation" in names:
            times = batch.column("message_log_time").cast("int64").to_pylist()
            for t, tr in zip(times, batch.column("Transform3D:translation").to_pylist()):
                robot.append((t, tr[0][0], tr[0][1]))
    robot.sort()
    return points, colours, robot


def rgba(packed):
    return tuple(((packed >> shift) & 0xFF) / 255 for shift in (24, 16, 8, 0))


def main():
    rrd, png = sys.argv[1], sys.argv[2]
    points, colours, robot = read(rrd)
    fig, ax = plt.subplots(figsize=(6.4, 6.4), dpi=120)
    ax.set_facecolor("#1b1d22")
    # The points come as the recorder writes them: cell centres on the floor (z = 0), then
    # the marks and the ball above it, then the four corners.
    body = points[:-4]
    cells = [(p, c) for p, c in zip(body, colours) if p[2] == 0]
    above = [(p, c) for p, c in zip(body, colours) if p[2] > 0]
    side = max(p[0] for p in points[-4:]) or 1.0
    cell_pt = 0.9 * 6.4 * 72 * (side / len(cells) ** 0.5) / (side * 1.25)
    for group, size, marker in ((cells, cell_pt**2, "s"), (above, 60, "o")):
        ax.scatter([p[0] for p, _ in group], [p[1] for p, _ in group],
                   c=[rgba(c) for _, c in group], s=size, marker=marker, edgecolors="none")
    corners = points[-4:]
    ax.plot([corners[i][0] for i in (0, 1, 3, 2, 0)], [corners[i][1] for i in (0, 1, 3, 2, 0)],
            color="#888", lw=1)
    # A jump of more than two cells is a new episode's start: the path breaks there.
    segments, current = [], []
    for _, x, y in robot:
        if current and (x - current[-1][0]) ** 2 + (y - current[-1][1]) ** 2 > 0.4 ** 2:
            segments.append(current)
            current = []
        current.append((x, y))
    segments.append(current)
    for i, seg in enumerate(segments):
        ax.plot([p[0] for p in seg], [p[1] for p in seg], color="#f5c518", lw=0.9, alpha=0.85,
                label="robot (/tf)" if i == 0 else None)
    if robot:
        ax.plot(robot[-1][1], robot[-1][2], marker="o", color="#f39c12", ms=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x, m (arena frame)")
    ax.set_ylabel("y, m")
    ax.set_title(f"{rrd}: /arena/points and /tf as Rerun decoded them")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(png)


if __name__ == "__main__":
    main()
