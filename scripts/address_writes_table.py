#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Issue 19's table for GPU-written inputs: capture cost, hazards found and false reports of
examples/cluster_scene --compute-infos (a compute shader writes the cluster builds' src infos
and count through buffer device addresses), with and without its barrier dispatch-to-sizes,
per capture mode (CLASTRACE_DEVICE_ADDRESS_WRITES off / cheap; exact is not implemented).

Each round runs every configuration once, in turn (interleaved), on lavapipe with the capture
layer serving the extension; times are the application's wall time and CPU time (user + system,
all its threads) under the layer, median of --rounds rounds. "serve only" is the layer with CLASTRACE_CAPTURE=0: the cost of serving alone.
A reported hazard is *true* when its earlier side is the dispatch and its byte overlap meets a
range the application says the dispatch wrote (its --json `computeWrites`); every other report is
false. The real hazards the missing barrier makes are known from the sample's design: the two
builds that read what the dispatch wrote (build:cluster-sizes and build:clusters) each read
srcInfosArray and srcInfosCount, and build:move reads the same cluster count as its
srcInfosCount, so 5 (build, field) pairs; "real hazards found" counts the distinct pairs the
true reports name.

Usage: scripts/address_writes_table.py [--build build] [--rounds 7] [--max-clusters 0]
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

LAVAPIPE = "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"
REAL_HAZARDS = 5  # (build, field) pairs without the barrier: see the docstring


def run_app(build, args, env_extra, trace):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("CLASTRACE_", "VK_"))}
    env.update({
        "VK_DRIVER_FILES": LAVAPIPE,
        "VK_ADD_LAYER_PATH": os.path.join(build, "capture", "manifest"),
        "VK_INSTANCE_LAYERS": "VK_LAYER_CLASTRACE_capture",
    })
    env.update(env_extra)
    if trace:
        env["CLASTRACE_OUTPUT"] = trace
    app = os.path.join(build, "examples", "cluster_scene", "cluster_scene")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([app, "--compute-infos", "--json"] + args, env=env,
                          capture_output=True, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    # CPU seconds (user + system, lavapipe's threads included): on a shared machine this moves
    # far less with the load than the wall time does.
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode != 0:
        sys.exit(f"cluster_scene failed ({done.returncode}): {done.stderr}")
    return seconds, cpu, json.loads(done.stdout)


def replay(build, trace):
    clastrace = os.path.join(build, "tools", "clastrace")
    done = subprocess.run([clastrace, "replay", "--json", trace], capture_output=True, text=True)
    if done.returncode not in (0, 1):
        sys.exit(f"clastrace replay failed ({done.returncode}): {done.stderr}")
    return json.loads(done.stdout)


def judge(report, app):
    """(true reports, false reports, real hazards found as a set of (build index, field))."""
    written = [(int(a), int(a) + int(n)) for a, n in app["scenes"][0]["computeWrites"]]
    true_reports, false_reports, found = 0, 0, set()
    for h in report.get("hazards", {}).get("hazards", []):
        begin, end = (int(x, 16) for x in h["overlap"])
        meets = any(begin < e and b < end for b, e in written)
        if h["prior"]["command"] == "vkCmdDispatch" and meets:
            true_reports += 1
            field = h["later"]["field"].split("[")[0]
            found.add((h["later"]["command_index"], field))
        else:
            false_reports += 1
    return true_reports, false_reports, found


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--build", default="build")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--max-clusters", type=int, default=0)
    options = parser.parse_args()
    base = ["--max-clusters", str(options.max_clusters)]
    configs = []  # (barrier, mode label, env, capture?)
    for barrier in (True, False):
        for label, env, capture in (("serve only", {"CLASTRACE_CAPTURE": "0"}, False),
                                    ("off", {"CLASTRACE_DEVICE_ADDRESS_WRITES": "off"}, True),
                                    ("cheap", {"CLASTRACE_DEVICE_ADDRESS_WRITES": "cheap"}, True)):
            configs.append((barrier, label, env, capture))
    times = {i: [] for i in range(len(configs))}
    cpus = {i: [] for i in range(len(configs))}
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(options.rounds):
            for i, (barrier, label, env, capture) in enumerate(configs):
                args = base + ([] if barrier else ["--skip-barrier", "dispatch-to-sizes"])
                trace = os.path.join(tmp, f"{i}.clt") if capture else None
                seconds, cpu, app = run_app(options.build, args, env, trace)
                times[i].append(seconds * 1000)
                cpus[i].append(cpu * 1000)
                if capture and i not in results:
                    report = replay(options.build, trace)
                    results[i] = (report, app, os.path.getsize(trace))
    print(f"examples/cluster_scene --compute-infos {' '.join(base)}, lavapipe, "
          f"median of {options.rounds} interleaved rounds")
    print("| barrier dispatch-to-sizes | mode | app ms under the layer | app CPU ms | trace bytes | "
          "certain | possible | true reports | false reports | real hazards found |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for i, (barrier, label, _, capture) in enumerate(configs):
        ms = statistics.median(times[i])
        cpu_ms = statistics.median(cpus[i])
        row = [("with" if barrier else "without"), label, f"{ms:.1f}", f"{cpu_ms:.1f}"]
        if capture:
            report, app, size = results[i]
            hazards = report.get("hazards", {})
            t, f, found = judge(report, app)
            want = 0 if barrier else REAL_HAZARDS
            row += [str(size), str(hazards.get("certain", 0)), str(hazards.get("possible", 0)),
                    str(t), str(f), f"{len(found)} of {want}"]
        else:
            row += ["-"] * 6
        print("| " + " | ".join(row) + " |")
    print("| with / without | exact | not implemented (capture/README.md gives the design) "
          "| | | | | | | |")


if __name__ == "__main__":
    main()
