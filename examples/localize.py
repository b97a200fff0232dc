#!/usr/bin/env python3
"""Localize photos against a visloc map from Python.

    scripts/setup.sh && scripts/demo.sh               # builds visloc and a demo map
    export PYTHONPATH=$PWD/build/python
    /usr/bin/python3 examples/localize.py MAP photo.jpg [photo2.jpg ...] [--focal PX | --intrinsics FILE]

Prints one line per photo: registered or not, confidence, position (WGS84
when the map is geo-registered) and heading, and the milliseconds it took.
"""

import argparse
import os
import sys

import visloc


def main():
    ap = argparse.ArgumentParser(description="Localize photos against a visloc map.")
    ap.add_argument("map", help="map directory (visloc map build / map import)")
    ap.add_argument("photos", nargs="+")
    ap.add_argument("--focal", type=float, help="focal length in pixels (default: EXIF, else estimated)")
    ap.add_argument("--intrinsics", help="per-photo intrinsics, 'name MODEL width height params...' per line")
    ap.add_argument("--min-confidence", type=float, help="registered at this confidence (default: the library's)")
    args = ap.parse_args()

    cameras = {}
    if args.intrinsics:
        for line in open(args.intrinsics):
            if line.strip() and not line.startswith("#"):
                name, model, width, height, *params = line.split()
                cameras[name] = (model, int(width), int(height), [float(p) for p in params])

    options = {}
    if args.min_confidence is not None:
        options["min_confidence"] = args.min_confidence
    try:
        localizer = visloc.Localizer(args.map, **options)
    except visloc.Error as e:
        sys.exit(f"error: {e}")

    for photo in args.photos:
        try:
            r = localizer.localize(photo, intrinsics=cameras.get(os.path.basename(photo), args.focal))
        except visloc.Error as e:
            print(f"{photo}: error: {e}")
            continue
        ms = r.times_ms["total"]
        if not r.registered:
            print(f"{photo}: not registered ({r.inliers} inliers, confidence {r.confidence:.2f}, {ms:.0f} ms)")
            continue
        where = (f"lat {r.lat:.7f} lon {r.lon:.7f} alt {r.alt:.1f} m, heading {r.heading_deg:.1f} deg"
                 if r.lat is not None else f"centre {r.pose.center.round(3).tolist()} (segment frame)")
        print(f"{photo}: {where}; segment {r.segment}, {r.inliers} inliers, confidence {r.confidence:.2f}, {ms:.0f} ms")


if __name__ == "__main__":
    main()
