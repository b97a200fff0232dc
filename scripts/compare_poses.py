#!/usr/bin/env python3
"""Compares two runs of examples/localize_photo (JSON lines), e.g. x86-64 and
aarch64: the same photos must come back with the same status, registration and
segment, and poses within tolerances (default 1 mm of camera centre, in metres
when the map is geo-registered, else in the segment's units, and 0.001 degrees
of rotation).

    scripts/compare_poses.py A.jsonl B.jsonl [--tolerance 0.001] [--rotation-tolerance 0.001]

Prints one line per photo and a summary; exit 0 when they agree, 1 otherwise,
2 on unreadable input."""
import argparse
import json
import math
import pathlib
import sys


def read_results(path):
    results = {}
    try:
        with open(path) as f:
            for number, line in enumerate(f, 1):
                line = line.strip()
                if not line:
                    continue
                try:
                    record = json.loads(line)
                except json.JSONDecodeError as e:
                    print(f"compare_poses: {path} line {number}: not JSON ({e})", file=sys.stderr)
                    sys.exit(2)
                if "image" in record:  # keyed by stem: q1.jpg (a file) and q1.pgm (its pixels) compare
                    results[pathlib.PurePath(record["image"]).stem] = record
    except OSError as e:
        print(f"compare_poses: cannot read {path}: {e.strerror}", file=sys.stderr)
        sys.exit(2)
    return results


def rotation_angle_deg(q1, q2):
    # 4 asin(|q1 - q2| / 2) for the nearer of ±q2: exact for small angles,
    # where 2 acos(q1·q2) loses every digit to rounding.
    chord = min(math.dist(q1, q2), math.dist(q1, [-c for c in q2]))
    return math.degrees(4 * math.asin(min(1.0, chord / 2)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("a")
    parser.add_argument("b")
    parser.add_argument("--tolerance", type=float, default=0.001,
                        help="largest camera-centre difference allowed (default 0.001: 1 mm)")
    parser.add_argument("--rotation-tolerance", type=float, default=0.001,
                        help="largest rotation difference allowed, degrees (default 0.001)")
    args = parser.parse_args()
    a, b = read_results(args.a), read_results(args.b)
    for path, results in ((args.a, a), (args.b, b)):
        if not results:
            print(f"compare_poses: no results in {path}", file=sys.stderr)
            return 2
    disagreements = 0
    worst_centre, worst_rotation, worst_inliers = 0.0, 0.0, 0
    for image in sorted(set(a) | set(b)):
        ra, rb = a.get(image), b.get(image)
        if ra is None or rb is None:
            print(f"{image}: only in {args.a if rb is None else args.b}")
            disagreements += 1
            continue
        if ra["status"] != rb["status"] or ra.get("registered") != rb.get("registered"):
            print(f"{image}: status {ra['status']}/{rb['status']}, registered {ra.get('registered')}/{rb.get('registered')}")
            disagreements += 1
            continue
        if ra["status"] != "ok" or ra.get("segment", -1) < 0:
            print(f"{image}: {ra['status']}, no pose on either")
            continue
        key = "enu" if "enu" in ra and "enu" in rb else "center"
        centre = math.dist(ra[key], rb[key])
        rotation = rotation_angle_deg(ra["rotation_wxyz"], rb["rotation_wxyz"])
        inliers = abs(ra["inliers"] - rb["inliers"])
        same_segment = ra["segment"] == rb["segment"]
        worst_centre, worst_rotation = max(worst_centre, centre), max(worst_rotation, rotation)
        worst_inliers = max(worst_inliers, inliers)
        ok = same_segment and centre <= args.tolerance and rotation <= args.rotation_tolerance
        disagreements += 0 if ok else 1
        print(f"{image}: registered {ra['registered']}, segment {ra['segment']}/{rb['segment']}, "
              f"inliers {ra['inliers']}/{rb['inliers']}, centre {centre:.3e} {'m' if key == 'enu' else 'units'}, "
              f"rotation {rotation:.2e} deg{'' if ok else '  DIFFERENT'}")
    print(f"summary: {len(set(a) | set(b))} photos, {disagreements} disagreements; largest centre difference "
          f"{worst_centre:.3e} ({'m' if any('enu' in r for r in a.values()) else 'segment units'}), rotation "
          f"{worst_rotation:.3e} deg, inlier count {worst_inliers}")
    return 1 if disagreements else 0


if __name__ == "__main__":
    sys.exit(main())
