#!/usr/bin/env python3
"""Python bindings benchmark (issue #16): the overhead of `visloc.Localizer.localize`
over the C++ localizer, and the throughput of two Python threads against one.

    PYTHONPATH=build/python /usr/bin/python3 bench/python_bench.py \
        [--map build/src/visloc/capi/fountain_map] [--scene ../shared/data/strecha/fountain-P11] \
        [--repeat 5] [--json OUT.json]

Overhead per query = Python's wall time around localize() minus the C++
localizer's own total (times_ms["total"], timed inside the library), for a
path and for a numpy frame; medians over every query and repetition.
Throughput: the same list of localizations run by one thread, then by a pool
of two (localize releases the GIL); the ratio of the median rates over
--repeat rounds. Run it on an otherwise idle machine with OMP_NUM_THREADS=1.
"""

import argparse
import concurrent.futures
import json
import os
import pathlib
import statistics
import sys
import time

import numpy as np

import visloc


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--map", default="build/src/visloc/capi/fountain_map")
    ap.add_argument("--scene", default="../shared/data/strecha/fountain-P11",
                    help="folder with images/, queries.txt and colmap/sparse/cameras.txt")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--max-features", type=int, default=16384)
    ap.add_argument("--json", help="also write the figures here")
    args = ap.parse_args()
    scene = pathlib.Path(args.scene)
    if not (scene / "queries.txt").exists() or not (pathlib.Path(args.map) / "manifest.json").exists():
        print(f"SKIP: needs {scene}/queries.txt and a map at {args.map}", file=sys.stderr)
        return 77
    names = (scene / "queries.txt").read_text().split()
    paths = [scene / "images" / n for n in names]
    cam = None
    for line in (scene / "colmap" / "sparse" / "cameras.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            _, model, w, h, *params = line.split()
            cam = (model, int(w), int(h), [float(p) for p in params])
            break
    visloc.set_opencv_threads(1)  # as the CLI: one core per query, so that threads do not compete
    loc = visloc.Localizer(args.map, max_features=args.max_features)
    frames = [visloc.read_image(p) for p in paths]
    for p in paths:  # warm the segment cache and the allocator
        loc.localize(p, intrinsics=cam)

    def overhead(items):
        out = []
        for _ in range(args.repeat):
            for item in items:
                t0 = time.perf_counter()
                r = loc.localize(item, intrinsics=cam)
                wall = (time.perf_counter() - t0) * 1e3
                out.append(wall - r.times_ms["total"])
        return out

    over_path = overhead(paths)
    over_frame = overhead(frames)

    work = paths * 4

    def run(threads):
        t0 = time.perf_counter()
        if threads == 1:
            for p in work:
                loc.localize(p, intrinsics=cam)
        else:
            with concurrent.futures.ThreadPoolExecutor(max_workers=threads) as pool:
                list(pool.map(lambda p: loc.localize(p, intrinsics=cam), work))
        return len(work) / (time.perf_counter() - t0)

    rates = {1: [], 2: []}
    for _ in range(args.repeat):  # interleaved, so that drift hits both alike
        rates[1].append(run(1))
        rates[2].append(run(2))
    one, two = statistics.median(rates[1]), statistics.median(rates[2])
    figures = {
        "queries": len(paths),
        "repeat": args.repeat,
        "cpus": os.cpu_count(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "overhead_ms_path": {"median": statistics.median(over_path), "max": max(over_path)},
        "overhead_ms_numpy": {"median": statistics.median(over_frame), "max": max(over_frame)},
        "queries_per_s_1_thread": one,
        "queries_per_s_2_threads": two,
        "speedup_2_threads": two / one,
        "rates_1_thread": rates[1],
        "rates_2_threads": rates[2],
    }
    print(f"overhead per query (ms, Python wall - C++ total): path median {figures['overhead_ms_path']['median']:.3f} "
          f"max {figures['overhead_ms_path']['max']:.3f}; numpy median {figures['overhead_ms_numpy']['median']:.3f} "
          f"max {figures['overhead_ms_numpy']['max']:.3f}")
    print(f"throughput: 1 thread {one:.2f} q/s, 2 threads {two:.2f} q/s, ratio {two / one:.2f}x "
          f"(medians of {args.repeat} rounds of {len(work)} localizations)")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
