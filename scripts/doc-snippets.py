#!/usr/bin/env python3
"""Runs the shell and Python code blocks of README.md and docs/*.md, as a reader would.

    python3 scripts/doc-snippets.py --tes target/debug/tes [--list] [FILE.md ...]

Every fenced block whose language is `sh`, `bash` or `python` runs in a scratch directory
(the repository's `data/`, `docs/`, `bench/`, `python/`, `scripts/` and
`bridge/` linked in, read-only in spirit: a block writing into them is a bug of the block),
with `tes` on `PATH` (the build under test, not a second release build: `cargo run
--release -p tes --` becomes `tes`), `TES_DATA_DIR` in the scratch directory, and a time
limit per block. Blocks of one file run in order in one scratch directory, so a block may
use what an earlier block of its file made (`tes launch --record run.mcap`, then
`tes replay run.mcap`).

A block that must not run here says so on the line before its fence:

    <!-- snippet: skip (needs an NXT brick on USB) -->

A block that serves until it is stopped (a bridge, a live view) says how long to let it run
before Ctrl-C (SIGINT to its process group); it passes if it then ends with status 0 or 130:

    <!-- snippet: stop after 3 s -->

A block of long runs (a benchmark, an experiment at the paper's settings: minutes to hours)
says how long to let each of its commands run: each line runs on its own and passes if it
ends with status 0 within that time, or is still running then and ends with 0 or 130 when
stopped — so every flag it names parses and the run starts, without taking its hours:

    <!-- snippet: each command stops after 10 s -->

The reason is required; `--list` prints every block with what will become of it. Files not
covered: docs/python.md (its blocks need the package installed; `python/tests` run it) and
docs/reliability.md (its fuzz and soak commands run for hours).
"""

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LANGUAGES = {"sh": "sh", "bash": "sh", "python": "python"}
FENCE = re.compile(r"^(\s*)```(\w+)\s*$")
SKIP = re.compile(r"^\s*<!--\s*snippet:\s*skip\s*\((.+)\)\s*-->\s*$")
STOP = re.compile(r"^\s*<!--\s*snippet:\s*stop after\s+(\d+(?:\.\d+)?)\s*s\s*-->\s*$")
EACH = re.compile(
    r"^\s*<!--\s*snippet:\s*each command stops after\s+(\d+(?:\.\d+)?)\s*s\s*-->\s*$")
# The exit statuses of a block stopped by Ctrl-C: finished anyway, 128 + SIGINT, or (a
# command run without a shell in between, which SIGINT ended) killed by SIGINT.
STOPPED_OK = {0, 130, -signal.SIGINT}
NOT_COVERED = {
    "docs/python.md": "its blocks need the tes Python package installed; python/tests run it",
    "docs/reliability.md": "its fuzz and soak commands run for hours",
}
LINKED = ["data", "bench", "python", "scripts", "bridge"]
# Copied, not linked: a started experiment writes its folder under docs/results/.
COPIED = ["docs"]
LIMIT_S = 600


class Block:
    def __init__(self, path, line, language, code, skip, stop_after=None, each=False):
        self.path, self.line, self.language, self.code, self.skip = (
            path, line, language, code, skip)
        self.stop_after = stop_after
        # Whether each line is a command of its own, stopped after `stop_after`.
        self.each = each

    def commands(self):
        """The block's commands: each line on its own (`each`), else the whole block."""
        if not self.each:
            return [self]
        return [Block(self.path, self.line + 1 + k, self.language, line, None,
                      self.stop_after)
                for k, line in enumerate(self.code.split("\n"))
                if line.strip() and not line.strip().startswith("#")]

    def where(self):
        return f"{self.path}:{self.line}"


def blocks_of(path):
    """The runnable blocks of the Markdown file `path` (relative to the repository)."""
    lines = (ROOT / path).read_text().split("\n")
    found, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, language = len(m.group(1)), m.group(2)
        end = i + 1
        while end < len(lines) and not re.match(r"^\s*```\s*$", lines[end]):
            end += 1
        if language in LANGUAGES:
            skip = SKIP.match(lines[i - 1]) if i > 0 else None
            stop = STOP.match(lines[i - 1]) if i > 0 else None
            each = EACH.match(lines[i - 1]) if i > 0 else None
            stop = stop or each
            code = "\n".join(l[indent:] for l in lines[i + 1:end])
            found.append(Block(path, i + 1, LANGUAGES[language], code,
                               skip.group(1) if skip else None,
                               float(stop.group(1)) if stop else None,
                               each is not None))
        i = end + 1
    return found


def as_run_here(code):
    """The block as it runs against the build under test."""
    return re.sub(r"cargo run (--release )?-p tes --", "tes", code)


def scratch_for(tes, tmp):
    """A scratch directory with the repository's inputs linked in and `tes` on PATH."""
    work = Path(tempfile.mkdtemp(dir=tmp))
    for name in LINKED:
        if (ROOT / name).exists():
            (work / name).symlink_to(ROOT / name)
    for name in COPIED:
        if (ROOT / name).exists():
            shutil.copytree(ROOT / name, work / name)
    bin_dir = work / ".bin"
    bin_dir.mkdir()
    (bin_dir / "tes").symlink_to(Path(tes).resolve())
    bridge = Path(tes).resolve().parent / "tes-bridge"
    if bridge.exists():
        (bin_dir / "tes-bridge").symlink_to(bridge)
    env = dict(os.environ)
    env["PATH"] = f"{bin_dir}:{env['PATH']}"
    env["TES_DATA_DIR"] = str(work / "tes-data")
    return work, env


def run(block, work, env):
    """Runs `block`; returns (ok, seconds, output)."""
    code = as_run_here(block.code)
    if block.language == "sh":
        command = ["bash", "-euo", "pipefail", "-c", code]
    else:
        command = [sys.executable, "-c", code]
    started = time.monotonic()
    # A process group of its own: a stop reaches every process the block started, as
    # Ctrl-C in a terminal would.
    process = subprocess.Popen(command, cwd=work, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                               start_new_session=True)
    try:
        if block.stop_after is not None:
            try:
                stdout, stderr = process.communicate(timeout=block.stop_after)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGINT)
                stdout, stderr = process.communicate(timeout=LIMIT_S)
            ok = process.returncode in STOPPED_OK
        else:
            stdout, stderr = process.communicate(timeout=LIMIT_S)
            ok = process.returncode == 0
        output = stdout + stderr
        if not ok:
            output += f"\n(exit status {process.returncode})"
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        ok = False
        output = f"{stdout}{stderr}\n(still running after {LIMIT_S} s)"
    return ok, time.monotonic() - started, output


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tes", required=True, help="the tes binary under test")
    parser.add_argument("--list", action="store_true", help="list the blocks, run nothing")
    parser.add_argument("files", nargs="*", help="Markdown files (default: README.md docs/*.md)")
    args = parser.parse_args()
    files = args.files or ["README.md"] + sorted(
        str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))
    failures, ran, skipped = [], 0, 0
    tmp = tempfile.mkdtemp(prefix="tes-doc-snippets-")
    try:
        for path in files:
            if path in NOT_COVERED:
                print(f"{path}: not covered ({NOT_COVERED[path]})")
                continue
            work, env = None, None
            for block in blocks_of(path):
                if block.skip:
                    skipped += 1
                    print(f"{block.where()}: skipped ({block.skip})")
                    continue
                if args.list:
                    each = " each command" if block.each else ""
                    how = (f" ({each.strip()} stopped after {block.stop_after:g} s)"
                           if block.stop_after is not None else "")
                    print(f"{block.where()}: runs{how}")
                    continue
                if work is None:
                    work, env = scratch_for(args.tes, tmp)
                for command in block.commands():
                    ok, seconds, output = run(command, work, env)
                    ran += 1
                    print(f"{command.where()}: {'ok' if ok else 'FAILED'} in {seconds:.1f} s",
                          flush=True)
                    if not ok:
                        failures.append(command.where())
                        print("    " + output.strip().replace("\n", "\n    "))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{ran} blocks or commands ran, {skipped} blocks skipped, {len(failures)} failed")
    if failures:
        print("failed: " + ", ".join(failures))
        sys.exit(1)


if __name__ == "__main__":
    main()
