#!/usr/bin/python3
"""Pair matchers of map building on the same segments, in one run (issues
#12 and #18). For every dataset it builds the map once per matcher (same
features, plan, options): `guided` and `colmap` (#12), and `twoview-VARIANT`,
i.e. `--matcher twoview --pair-ransac VARIANT` (our exact matching verified
by two-view RANSAC: classic, 1m or 1m-sprt, #18). Then it localizes the same
queries on every map, and writes a per-segment table (seconds per stage,
points, points with track >= 3, mean track length, mean reprojection error),
the points per matcher and the localization summary to OUT/report.md and
OUT/report.json.

    bench/map_matchers.py --out DIR --dataset NAME:IMAGES:GPS:POSES[:INTRINSICS] \\
        [--queries LIST:IMAGES:TRUTH:INTRINSICS] [--dataset ... --queries ...] [--jobs N] \\
        [--matchers guided,colmap,twoview-1m-sprt,twoview-classic] [--poses known|sfm]

Each --queries belongs to the --dataset before it. With --poses sfm, POSES is
not used and TRUTH should be a GPS CSV (eval compares ENU centres; an SfM
map's segment frames are COLMAP's). Finished builds are reused (map build
resumes), so an interrupted run continues.
"""
import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# VISLOC in the environment: another binary (e.g. a copy, while build/ is rebuilt).
VISLOC = os.environ.get("VISLOC") or os.path.join(ROOT, "build", "src", "visloc", "cli", "visloc")


def run(cmd, log):
    with open(log, "a") as f:
        f.write("$ " + " ".join(cmd) + "\n")
        f.flush()
        t = time.time()
        p = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
        f.write(f"(exit {p.returncode}, {time.time() - t:.1f} s)\n")
    if p.returncode != 0:
        sys.exit(f"map_matchers: failed (exit {p.returncode}): {' '.join(cmd)}; log: {log}")
    return time.time() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--dataset", action="append", default=[], help="NAME:IMAGES:GPS:POSES[:INTRINSICS]")
    ap.add_argument("--queries", action="append", default=[], help="LIST:IMAGES:TRUTH:INTRINSICS (one per dataset)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--matchers", default="guided,colmap",
                    help="comma-separated: guided, colmap, auto, twoview-classic, twoview-1m, twoview-1m-sprt")
    ap.add_argument("--poses", choices=["known", "sfm"], default="known")
    a = ap.parse_args()
    if not a.dataset:
        ap.error("give at least one --dataset")
    if a.queries and len(a.queries) != len(a.dataset):
        ap.error("give one --queries per --dataset (or none)")
    if not os.access(VISLOC, os.X_OK):
        sys.exit(f"map_matchers: {VISLOC} is missing; run scripts/setup.sh")
    os.makedirs(a.out, exist_ok=True)
    log = os.path.join(a.out, "log.txt")
    report = {"datasets": []}
    lines = [f"# Pair matchers of map building (same segments, one run; poses: {a.poses})", ""]
    for k, spec in enumerate(a.dataset):
        parts = spec.split(":")
        if len(parts) not in (4, 5):
            ap.error(f"--dataset {spec}: want NAME:IMAGES:GPS:POSES[:INTRINSICS]")
        name, images, gps, poses = parts[:4]
        ds = {"name": name, "maps": {}}
        for matcher in a.matchers.split(","):
            mdir = os.path.join(a.out, f"{name}-{matcher}")
            cmd = [VISLOC, "map", "build", "--images", images, "--gps", gps, "--poses", a.poses,
                   "--out", mdir, "--jobs", str(a.jobs)]
            if matcher.startswith("twoview-"):
                cmd += ["--matcher", "twoview", "--pair-ransac", matcher[len("twoview-"):]]
            else:
                cmd += ["--matcher", matcher]
            if a.poses == "known":
                cmd += ["--known-poses", poses]
                if len(parts) == 5:
                    cmd += ["--known-intrinsics", parts[4]]
            wall = run(cmd, log)
            segs = []
            for d in sorted(os.listdir(os.path.join(mdir, "work"))):
                rf = os.path.join(mdir, "work", d, "result.json")
                if d.startswith("seg") and os.path.exists(rf):
                    segs.append(json.load(open(rf)))
            entry = {"wall_s_last_run": wall, "segments": segs}
            if a.queries:
                qlist, qimages, truth, intr = a.queries[k].split(":")
                rdir = os.path.join(a.out, f"{name}-{matcher}-report")
                run([VISLOC, "eval", "--map", mdir, "--queries", qlist, "--images", qimages, "--truth", truth,
                     "--intrinsics", intr, "--out", rdir], log)
                r = json.load(open(os.path.join(rdir, "report.json")))
                entry["localization"] = {"queries": r["queries"], "registered": r["registered"],
                                         "wrong_poses": r.get("wrong_poses"),
                                         "median_position_error_m": r["position_error_m"]["median"],
                                         "median_rotation_error_deg": r["rotation_error_deg"]["median"]}
            ds["maps"][matcher] = entry
        report["datasets"].append(ds)

        lines += [f"## {name}", "",
                  "| matcher | seg | images | pairs | database s | matching s | triangulation+BA s | compression s | "
                  "segment s | points | track>=3 | mean track | mean reproj px |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for matcher, e in ds["maps"].items():
            for s in e["segments"]:
                if not s.get("ok"):
                    lines.append(f"| {matcher} | {s['id']} | FAILED: {s.get('error', '')} |")
                    continue
                lines.append(
                    f"| {matcher} | {s['id']} | {s['images']} | {s.get('pairs', 0)} | {s['seconds_database']:.1f} | "
                    f"{s['seconds_matching']:.1f} | {s['seconds_triangulation']:.1f} | {s['seconds_compression']:.1f} | "
                    f"{s['seconds']:.1f} | {s['points']} | {s['points_track3']} | {s['mean_track_length']:.2f} | "
                    f"{s['mean_reprojection_error']:.2f} |")
        names = list(ds["maps"])
        if len(names) == 2 and all(s.get("ok") for m in names for s in ds["maps"][m]["segments"]):
            g, c = (ds["maps"][n]["segments"] for n in names)
            ratio = lambda key: sum(s[key] for s in c) / max(1e-9, sum(s[key] for s in g))
            lines += ["", f"Totals over segments, {names[1]} ÷ {names[0]}: matching {ratio('seconds_matching'):.1f}×, "
                      f"whole segment {ratio('seconds'):.1f}×; points with track ≥ 3: "
                      f"{sum(s['points_track3'] for s in g)} vs {sum(s['points_track3'] for s in c)} "
                      f"({100 * sum(s['points_track3'] for s in g) / max(1, sum(s['points_track3'] for s in c)):.0f}%)"]
        lines += ["", "| matcher | points (all segments) | track >= 3 | pairs verified / given | matches written |",
                  "|---|---|---|---|---|"]
        for matcher, e in ds["maps"].items():
            ok = [s for s in e["segments"] if s.get("ok")]
            verified = f"{sum(s.get('matched_pairs', 0) for s in ok)} / {sum(s.get('pairs', 0) for s in ok)}"
            lines.append(f"| {matcher} | {sum(s['points'] for s in ok)} | {sum(s['points_track3'] for s in ok)} | "
                         f"{verified if matcher != 'colmap' else '(COLMAP)'} | "
                         f"{sum(s.get('matches', 0) for s in ok) if matcher != 'colmap' else '(COLMAP)'} |")
        if a.queries:
            lines += ["", "| matcher | registered | median position error m | median rotation error deg |", "|---|---|---|---|"]
            for matcher, e in ds["maps"].items():
                l = e["localization"]
                lines.append(f"| {matcher} | {l['registered']}/{l['queries']} | {l['median_position_error_m']:.3f} | "
                             f"{l['median_rotation_error_deg']:.2f} |")
        lines.append("")
    with open(os.path.join(a.out, "report.json"), "w") as f:
        json.dump(report, f, indent=2)
    with open(os.path.join(a.out, "report.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
