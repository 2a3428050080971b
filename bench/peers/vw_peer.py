"""mDAGL (`tes fit`) and Vowpal Wabbit side by side on the same rows, in one run.

Run through `bench/peers/run`, which makes the virtual environment with `vowpalwabbit` from
PyPI and the rows; by hand:

    python bench/peers/vw_peer.py ROWS.csv --tes target/release/tes [--json]

ROWS.csv is a labelled CSV stream as `tes fit` reads it (label 0..K-1, then 0/1 features).
From it this writes the same rows as libsvm text (for `tes fit`) and as Vowpal Wabbit text
(`label+1 | columns`, VW's classes being 1..K), then measures:

* VW's own C++ driver over its text file: `--oaa K --loss_function logistic --probabilities
  -d FILE` (reading, parsing and learning; the rows per second of the whole pass);
* VW's learning pass alone, on examples parsed beforehand (one `learn` call per row from
  Python), and its prequential log-loss: the probabilities each `learn` predicted for its row
  before learning from it;
* `tes fit --json` with the paper's setting and with `--lambda auto --alpha auto` (on every
  core, and on one thread with `--threads 1`): its own
  figure (the model's work: predicting then learning each row), the whole command over the
  libsvm file (reading both passes, parsing and learning), and the prequential log-loss.

Each timing is the median of `--repeats` runs, taken in rounds of one run of each. Prints a table, or one JSON object with
`--json`.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

import vowpalwabbit


def read_csv(path):
    """The rows as (label, [columns that are 1])."""
    rows = []
    with open(path) as f:
        for number, line in enumerate(f, 1):
            fields = line.strip().split(",")
            if not fields or fields == [""]:
                continue
            label = int(fields[0])
            on = [i for i, v in enumerate(fields[1:]) if v == "1"]
            if any(v not in ("0", "1") for v in fields[1:]):
                sys.exit(f"{path}:{number}: only 0/1 features are compared")
            rows.append((label, on))
    return rows


def write_sparse(rows, libsvm_path, vw_path):
    with open(libsvm_path, "w") as svm, open(vw_path, "w") as vw:
        for label, on in rows:
            svm.write(f"{label} " + " ".join(f"{c}:1" for c in on) + "\n")
            vw.write(f"{label + 1} | " + " ".join(str(c) for c in on) + "\n")


def vw_args(classes):
    return f"--oaa {classes} --loss_function logistic --probabilities --quiet"


def vw_driver(vw_path, classes, rows):
    """VW's C++ driver over its text file: rows per second of the whole pass."""
    start = time.perf_counter()
    ws = vowpalwabbit.Workspace(f"{vw_args(classes)} -d {vw_path}")
    ws.run_parser()
    seconds = time.perf_counter() - start
    seen = ws.get_weighted_examples()
    ws.finish()
    if int(seen) != rows:
        sys.exit(f"VW's driver saw {seen} rows of {rows}")
    return rows / seconds


def vw_learning_pass(vw_path, rows, classes):
    """VW's learn calls on pre-parsed examples: rows per second and prequential log-loss."""
    ws = vowpalwabbit.Workspace(vw_args(classes))
    with open(vw_path) as f:
        examples = [ws.parse(line.rstrip("\n")) for line in f]
    start = time.perf_counter()
    for example in examples:
        ws.learn(example)
    seconds = time.perf_counter() - start
    loss = 0.0
    for example, (label, _) in zip(examples, rows):
        probs = example.get_prediction()
        loss -= math.log(max(probs[label], 1e-300))
    ws.finish()
    return len(rows) / seconds, loss / len(rows)


def tes_fit(tes, path, args):
    start = time.perf_counter()
    out = subprocess.run(
        [tes, "fit", path, "--json", *args], check=True, capture_output=True, text=True
    )
    seconds = time.perf_counter() - start
    report = json.loads(out.stdout)
    report["command_rows_per_sec"] = report["n"] / seconds
    return report


def median_by(runs, key):
    """The run with the median `key` (the upper one of an even count)."""
    runs = sorted(runs, key=key)
    return runs[len(runs) // 2]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv", help="labelled CSV rows (label, then 0/1 features)")
    parser.add_argument("--tes", default=os.environ.get("TES_BIN", "tes"), help="the tes binary")
    parser.add_argument("--repeats", type=int, default=3, help="runs per timing (median)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()

    rows = read_csv(args.csv)
    classes = max(label for label, _ in rows) + 1
    with tempfile.TemporaryDirectory() as work:
        libsvm = os.path.join(work, "rows.svm")
        vw_text = os.path.join(work, "rows.vw")
        write_sparse(rows, libsvm, vw_text)
        settings = {
            "paper": [],
            "auto": ["--lambda", "auto", "--alpha", "auto"],
            "auto, one thread": ["--lambda", "auto", "--alpha", "auto", "--threads", "1"],
        }
        # Interleaved: one run of each per round, so a slow spell of a shared host falls on
        # every contender alike.
        drivers, learns, fit_runs = [], [], {name: [] for name in settings}
        for _ in range(args.repeats):
            drivers.append(vw_driver(vw_text, classes, len(rows)))
            learns.append(vw_learning_pass(vw_text, rows, classes))
            for name, extra in settings.items():
                fit_runs[name].append(tes_fit(args.tes, libsvm, extra))
        driver = statistics.median(drivers)
        learn_rate, vw_loss = median_by(learns, key=lambda r: r[0])
        fits = {
            name: median_by(runs, key=lambda r: r["updates_per_sec"])
            for name, runs in fit_runs.items()
        }

    result = {
        "rows": len(rows),
        "classes": classes,
        "features": max((c for _, on in rows for c in on), default=-1) + 1,
        "vowpalwabbit": {
            "version": vowpalwabbit.__version__,
            "options": vw_args(classes),
            "driver_rows_per_sec": driver,
            "learn_rows_per_sec": learn_rate,
            "mean_logloss": vw_loss,
        },
        "mdagl": {
            name: {
                "lambda": fit["lambda"],
                "alpha": fit["alpha"],
                "selected": len(fit["selected"]),
                "updates_per_sec": fit["updates_per_sec"],
                "command_rows_per_sec": fit["command_rows_per_sec"],
                "mean_logloss": fit["mean_logloss"],
                "logloss_vs_vw": fit["mean_logloss"] / vw_loss,
                "updates_vs_vw_learn": fit["updates_per_sec"] / learn_rate,
                "command_vs_vw_driver": fit["command_rows_per_sec"] / driver,
            }
            for name, fit in fits.items()
        },
    }
    if args.json:
        print(json.dumps(result))
    else:
        print_table(result)


def print_table(r):
    vw = r["vowpalwabbit"]
    print(
        f"{r['rows']} rows, {r['features']} binary features, {r['classes']} classes "
        f"(vowpalwabbit {vw['version']}: {vw['options']})"
    )
    print(f"{'':52} {'log-loss':>9} {'learning rows/s':>16} {'whole pass rows/s':>18}")
    print(
        f"{'Vowpal Wabbit':52} {vw['mean_logloss']:9.4f} {vw['learn_rows_per_sec']:16,.0f} "
        f"{vw['driver_rows_per_sec']:18,.0f}"
    )
    for name, m in r["mdagl"].items():
        label = f"mDAGL {name} (lambda {m['lambda']:g}, alpha {m['alpha']:g})"
        print(
            f"{label:52} {m['mean_logloss']:9.4f} {m['updates_per_sec']:16,.0f} "
            f"{m['command_rows_per_sec']:18,.0f}"
        )
    for name, m in r["mdagl"].items():
        print(
            f"mDAGL {name} / VW: log-loss {m['logloss_vs_vw']:.4f}x, learning "
            f"{m['updates_vs_vw_learn']:.1f}x, whole pass {m['command_vs_vw_driver']:.1f}x "
            f"({m['selected']} features kept)"
        )


if __name__ == "__main__":
    main()
