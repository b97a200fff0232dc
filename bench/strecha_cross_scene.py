#!/usr/bin/python3
"""Strecha queries against another scene's map, judged in a common frame (issue #14).

fountain-P11, entry-P10, castle-P19 and castle-P30 were taken at one site, but
each scene's ground truth is in a frame of its own, so a query of scene B that
registers against scene A's map cannot be called right or wrong from the
ground truth alone. This runner finds out:

1. COLMAP reconstructs all the scenes' images together (SIFT, exhaustive
   matching, mapper; the scenes' shared ground-truth intrinsics, fixed).
2. For each scene, a similarity from the joint model's frame to the scene's
   ground-truth frame, fitted on the scene's camera centres (Umeyama); its
   residuals say how well it holds.
3. Which scene pairs overlap: the joint 3D points seen by both scenes' images.
4. For each ordered pair (map A, queries B): every photo of B that the joint
   model holds in A's model gets a reference pose in A's frame and is a
   query; B's photos identical byte for byte to one of A's are left out (not
   a cross-scene query), and photos without a reference are unscored.
   `visloc eval` scores the queries against A's map (imported from A's COLMAP
   model, A's holdouts out), counting a pose more than 5 m or 10 degrees from
   the reference as wrong.

With `--focal estimated` the queries get no intrinsics (the localizer
estimates the focal length). Writes WORK/report-{known,estimated}.md and
.json; resumable (each stage is skipped
when its output exists). Needs COLMAP and numpy.

  bench/strecha_cross_scene.py --work DIR [--shared-data ../shared/data]
      [--visloc build/src/visloc/cli/visloc] [--max-features 16384] [--scenes a,b,...]
      [--focal known|estimated]
"""
import argparse
import functools
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SCENES = ["fountain-P11", "entry-P10", "castle-P19", "castle-P30"]


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] strecha_cross_scene: {msg}", file=sys.stderr, flush=True)


def run(cmd, log_file):
    log(" ".join(str(c) for c in cmd[:3]) + " ...")
    with open(log_file, "a") as f:
        f.write("$ " + " ".join(str(c) for c in cmd) + "\n")
        f.flush()
        r = subprocess.run([str(c) for c in cmd], stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        sys.exit(f"strecha_cross_scene: {cmd[0]} {cmd[1]} failed (exit {r.returncode}); see {log_file}")


def read_strecha_camera(path):
    """K, R (camera-to-world), C, width, height from Strecha's .camera file."""
    v = [float(x) for x in Path(path).read_text().split()]
    if len(v) != 26:
        sys.exit(f"strecha_cross_scene: {path}: expected 26 numbers, found {len(v)}")
    K = np.array(v[0:9]).reshape(3, 3)
    R = np.array(v[12:21]).reshape(3, 3)
    return K, R, np.array(v[21:24]), int(v[24]), int(v[25])


def quat_to_rot(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rot_to_quat(R):
    """Unit quaternion (w, x, y, z), w >= 0, by Shepperd's method: from the
    largest of 4w², 4x², 4y², 4z², so it stays exact at 180° rotations."""
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        w = np.sqrt(1 + tr) / 2
        q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    else:
        i, j, l = k - 1, k % 3, (k + 1) % 3
        v = np.zeros(3)
        v[i] = np.sqrt(max(0.0, 1 + R[i, i] - R[j, j] - R[l, l])) / 2
        v[j] = (R[j, i] + R[i, j]) / (4 * v[i])
        v[l] = (R[l, i] + R[i, l]) / (4 * v[i])
        q = np.array([(R[l, j] - R[j, l]) / (4 * v[i]), *v])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def umeyama(src, dst):
    """s, R, t minimizing sum |dst - (s R src + t)|^2 (Umeyama 1991)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = (xs ** 2).sum() / len(src)
    s = np.trace(np.diag(D) @ S) / var_s
    return s, R, mu_d - s * R @ mu_s


def read_text_model(model_txt):
    """Images: name -> (R cam_from_world, t, image id); points: list of image-id sets."""
    images, lines = {}, [l for l in (model_txt / "images.txt").read_text().splitlines() if not l.startswith("#")]
    for i in range(0, len(lines) - 1, 2):
        f = lines[i].split()
        if len(f) < 10:
            continue
        q, t = np.array([float(x) for x in f[1:5]]), np.array([float(x) for x in f[5:8]])
        images[f[9]] = (quat_to_rot(q), t, int(f[0]))
    tracks = []
    for l in (model_txt / "points3D.txt").read_text().splitlines():
        if l.startswith("#") or not l.strip():
            continue
        f = l.split()
        tracks.append({int(x) for x in f[8::2]})
    return images, tracks


def joint_reconstruction(args, work, logf):
    """COLMAP on every scene's images; returns the text export of each model found."""
    joint = work / "joint"
    images = joint / "images"
    images.mkdir(parents=True, exist_ok=True)
    K = None
    for scene in args.scenes:
        for img in sorted((args.shared_data / "strecha" / scene / "images").glob("*.jpg")):
            link = images / f"{scene}__{img.name}"
            if not link.exists():
                link.symlink_to(img.resolve())
        K_s, _, _, _, _ = read_strecha_camera(next((args.shared_data / "strecha" / scene / "cameras").glob("*.camera")))
        if K is not None and not np.allclose(K, K_s):
            sys.exit(f"strecha_cross_scene: {scene}'s intrinsics differ from the other scenes'; one camera is assumed")
        K = K_s
    sparse = joint / "sparse"
    if not (joint / "mapper.done").exists():
        db = joint / "database.db"
        if db.exists():
            db.unlink()
        shutil.rmtree(sparse, ignore_errors=True)
        sparse.mkdir()
        params = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"
        run(["colmap", "feature_extractor", "--database_path", db, "--image_path", images,
             "--ImageReader.single_camera", "1", "--ImageReader.camera_model", "PINHOLE",
             "--ImageReader.camera_params", params, "--SiftExtraction.use_gpu", "0",
             "--SiftExtraction.max_num_features", "4096"], logf)
        run(["colmap", "exhaustive_matcher", "--database_path", db, "--SiftMatching.use_gpu", "0"], logf)
        run(["colmap", "mapper", "--database_path", db, "--image_path", images, "--output_path", sparse,
             "--Mapper.ba_refine_focal_length", "0", "--Mapper.ba_refine_extra_params", "0"], logf)
        (joint / "mapper.done").write_text("done\n")
    models = []
    for m in sorted(p for p in sparse.iterdir() if p.is_dir() and not p.name.endswith("_txt")):
        txt = sparse / (m.name + "_txt")
        if not (txt / "images.txt").exists():
            txt.mkdir(exist_ok=True)
            run(["colmap", "model_converter", "--input_path", m, "--output_path", txt, "--output_type", "TXT"], logf)
        models.append(read_text_model(txt))
    if not models:
        sys.exit(f"strecha_cross_scene: COLMAP made no model in {sparse}; see {logf}")
    return models


def scene_truth(args, scene):
    """name -> (R cam_from_world, t) in the scene's ground-truth frame, from truth.txt."""
    out = {}
    for l in (args.shared_data / "strecha" / scene / "truth.txt").read_text().splitlines():
        f = l.split()
        if len(f) == 8 and not l.startswith("#"):
            out[f[0]] = (quat_to_rot(np.array([float(x) for x in f[1:5]])), np.array([float(x) for x in f[5:8]]))
    return out


def align_scenes(args, models):
    """Per scene: the model holding most of its images and the similarity joint -> ground truth."""
    alignment = {}
    for scene in args.scenes:
        truth = scene_truth(args, scene)
        best = max(range(len(models)), key=lambda m: sum(n.startswith(scene + "__") for n in models[m][0]))
        images = models[best][0]
        names = [n for n in truth if f"{scene}__{n}" in images]
        if len(names) < 3:
            alignment[scene] = {"model": None, "images_in_model": len(names), "images": len(truth)}
            continue
        joint_c = np.array([-images[f"{scene}__{n}"][0].T @ images[f"{scene}__{n}"][1] for n in names])
        truth_c = np.array([-truth[n][0].T @ truth[n][1] for n in names])
        s, R, t = umeyama(joint_c, truth_c)
        residual = np.linalg.norm(truth_c - (s * (R @ joint_c.T).T + t), axis=1)
        alignment[scene] = {"model": best, "images_in_model": len(names), "images": len(truth), "s": s, "R": R,
                            "t": t, "residual_median_m": float(np.median(residual)),
                            "residual_max_m": float(residual.max())}
    return alignment


def overlap(models, alignment, a, b):
    """Joint 3D points seen by an image of scene a and an image of scene b in a's model, or None (a not aligned)."""
    if alignment[a]["model"] is None:
        return None
    images, tracks = models[alignment[a]["model"]]
    ids_a = {v[2] for n, v in images.items() if n.startswith(a + "__")}
    ids_b = {v[2] for n, v in images.items() if n.startswith(b + "__")}
    return sum(1 for tr in tracks if tr & ids_a and tr & ids_b)


def import_map(args, work, scene, logf):
    d = args.shared_data / "strecha" / scene
    out = work / "maps" / scene
    if not (out / "manifest.json").exists():
        shutil.rmtree(out, ignore_errors=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        run([args.visloc, "map", "import", "--colmap", d / "colmap" / "sparse", "--database",
             d / "colmap" / "database.db", "--holdout", d / "queries.txt", "--out", out], logf)
    return out


def reference_pose_in_map_frame(R_q, t_q, al):
    """cam_from_map (R, t) of a camera whose cam_from_joint is (R_q, t_q), when
    x_map = s R x_joint + t: x_cam = R_q x_joint + t_q, in the map's units
    s x_cam = (R_q R^T) x_map + s t_q - R_q R^T t."""
    R = R_q @ al["R"].T
    return R, al["s"] * t_q - R @ al["t"]


@functools.lru_cache(maxsize=None)
def scene_image_digests(shared_data, scene):
    """File name -> SHA-256 of the scene's images (castle-P19 and castle-P30
    share ten photos byte for byte); read once per scene, not once per pair."""
    return {img.name: hashlib.sha256(img.read_bytes()).hexdigest()
            for img in sorted((shared_data / "strecha" / scene / "images").glob("*.jpg"))}


def write_pair_inputs(args, pair_dir, models, alignment, a, b):
    """B's queries with references in A's frame and B's intrinsics. B's photos
    identical to one of A's are left out (not a cross-scene query), and so are
    those the joint model does not hold in A's model (no reference: unscored)."""
    pair_dir.mkdir(parents=True, exist_ok=True)
    d = args.shared_data / "strecha" / b
    al = alignment[a]
    images = models[al["model"]][0] if al["model"] is not None else {}
    digests_a = set(scene_image_digests(args.shared_data, a).values())
    digests_b = scene_image_digests(args.shared_data, b)
    queries, truth_lines, intr, identical, unscored = [], [], [], [], []
    for cam in sorted((d / "cameras").glob("*.camera")):
        name = cam.name[: -len(".camera")]
        K, _, _, w, h = read_strecha_camera(cam)
        if digests_b.get(name) in digests_a:
            identical.append(name)
            continue
        joint = images.get(f"{b}__{name}")
        if joint is None or al["model"] is None:
            unscored.append(name)
            continue
        R, t = reference_pose_in_map_frame(joint[0], joint[1], al)
        q = rot_to_quat(R)
        queries.append(name)
        truth_lines.append(f"{name} " + " ".join(f"{x:.9f}" for x in [*q, *t]))
        # Strecha's K has pixel centres at integers; visloc's top-left pixel centre is at (0.5, 0.5).
        intr.append(f"{name} PINHOLE {w} {h} {K[0, 0]} {K[1, 1]} {K[0, 2] + 0.5} {K[1, 2] + 0.5}")
    (pair_dir / "queries.txt").write_text("".join(n + "\n" for n in queries))
    (pair_dir / "truth.txt").write_text("".join(l + "\n" for l in truth_lines))
    (pair_dir / "intrinsics.txt").write_text("".join(l + "\n" for l in intr))
    return queries, identical, unscored


def inputs_stamp(args, pair_dir):
    """What an eval of this pair depends on: its input files and the options."""
    h = hashlib.sha256(f"max_features={args.max_features} focal={args.focal}\n".encode())
    for f in ("queries.txt", "truth.txt", "intrinsics.txt"):
        h.update((pair_dir / f).read_bytes())
    return h.hexdigest()


def evaluate_pair(args, work, models, alignment, a, b, logf):
    pair_dir = work / "pairs" / args.focal / f"{a}__vs__{b}"
    queries, identical, unscored = write_pair_inputs(args, pair_dir, models, alignment, a, b)
    counts = {"queries": len(queries), "identical_photos_left_out": len(identical), "unscored": len(unscored)}
    if not queries:
        return counts
    out, stamp_file = pair_dir / "eval", pair_dir / "eval.done"
    stamp = inputs_stamp(args, pair_dir)
    if not stamp_file.exists() or stamp_file.read_text() != stamp:  # new, changed or interrupted: run again
        stamp_file.unlink(missing_ok=True)
        shutil.rmtree(out, ignore_errors=True)
        cmd = [args.visloc, "eval", "--map", work / "maps" / a, "--images", args.shared_data / "strecha" / b / "images",
               "--queries", pair_dir / "queries.txt", "--truth", pair_dir / "truth.txt",
               "--max-features", str(args.max_features), "--out", out]
        cmd += ["--intrinsics", pair_dir / "intrinsics.txt"] if args.focal == "known" else ["--no-exif-focal"]
        run(cmd, logf)
        stamp_file.write_text(stamp)
    return counts | summarize(out)


def summarize(out):
    try:
        rep = json.loads((out / "report.json").read_text())
        results = [json.loads(l) for l in (out / "results.jsonl").read_text().splitlines() if l.strip()]
    except (OSError, ValueError) as e:
        sys.exit(f"strecha_cross_scene: {out}: cannot read the eval's report ({e}); delete {out} and run again")
    by_image = {r["image"]: r for r in results}
    pos = rep.get("position_error_m") or {}
    wrong, sigma_ratios = [], []
    for q in rep["per_query"]:
        r = by_image.get(q["image"], {})
        if not r.get("registered"):
            continue
        sigma = (r.get("uncertainty") or {}).get("position_sigma")
        if sigma:
            sigma_ratios.append(q["position_error_m"] / sigma)
        if q["position_error_m"] > 5 or q["rotation_error_deg"] > 10:
            wrong.append({"image": q["image"], "position_error_m": q["position_error_m"],
                          "rotation_error_deg": q["rotation_error_deg"], "inliers": r.get("inliers"),
                          "confidence": r.get("confidence"), "position_sigma": sigma})
    return {"registered": rep["registered"], "wrong_poses": rep["wrong_poses"]["positives"], "wrong": wrong,
            "error_over_sigma": sigma_ratios, "median_position_error_m": pos.get("median")}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    root = Path(__file__).resolve().parent.parent
    p.add_argument("--work", type=Path, required=True, help="work and report folder (resumable)")
    p.add_argument("--shared-data", type=Path, default=root.parent / "shared" / "data")
    p.add_argument("--visloc", type=Path, default=root / "build" / "src" / "visloc" / "cli" / "visloc")
    p.add_argument("--max-features", type=int, default=16384, help="query SIFT budget (the Strecha evals' setting)")
    p.add_argument("--scenes", default=",".join(SCENES), help="comma-separated Strecha scenes")
    p.add_argument("--focal", choices=["known", "estimated"], default="known",
                   help="queries with their true intrinsics, or none (the focal length estimated)")
    args = p.parse_args()
    args.scenes = [s for s in args.scenes.split(",") if s]
    for s in args.scenes:
        if not (args.shared_data / "strecha" / s / "truth.txt").exists():
            sys.exit(f"strecha_cross_scene: {args.shared_data / 'strecha' / s} has no truth.txt")
    if len(args.scenes) < 2:
        sys.exit("strecha_cross_scene: give at least two scenes")
    if not os.access(args.visloc, os.X_OK):
        sys.exit(f"strecha_cross_scene: {args.visloc} is not an executable; run scripts/setup.sh")
    if shutil.which("colmap") is None:
        sys.exit("strecha_cross_scene: COLMAP is not on PATH")
    args.work.mkdir(parents=True, exist_ok=True)
    args.work = args.work.resolve()
    logf = args.work / "log.txt"
    models = joint_reconstruction(args, args.work, logf)
    alignment = align_scenes(args, models)
    for s in args.scenes:
        import_map(args, args.work, s, logf)
    pairs = {}
    for a in args.scenes:
        for b in args.scenes:
            if a != b:
                log(f"map {a}, queries {b}")
                r = evaluate_pair(args, args.work, models, alignment, a, b, logf)
                r["shared_points"] = overlap(models, alignment, a, b)
                pairs[f"{a} <- {b}"] = r
    write_report(args, models, alignment, pairs)


def write_report(args, models, alignment, pairs):
    al_json = {s: {k: v for k, v in a.items() if k not in ("R", "t")} | ({"scale": a["s"]} if "s" in a else {})
               for s, a in alignment.items()}
    for a in al_json.values():
        a.pop("s", None)
    (args.work / f"report-{args.focal}.json").write_text(json.dumps(
        {"focal": args.focal, "models": [len(m[0]) for m in models], "alignment": al_json, "pairs": pairs}, indent=2))
    md = [f"# Strecha queries against another scene's map, judged in a common frame ({args.focal} focal)\n",
          f"Joint COLMAP reconstruction of {', '.join(args.scenes)}: {len(models)} model(s) of "
          f"{', '.join(str(len(m[0])) for m in models)} images.\n",
          "| scene | model | images in it | alignment residual median / max (m) |", "|---|---|---|---|"]
    for s, a in alignment.items():
        res = "–" if a["model"] is None else f"{a['residual_median_m']:.3f} / {a['residual_max_m']:.3f}"
        md.append(f"| {s} | {a['model']} | {a['images_in_model']}/{a['images']} | {res} |")
    md += ["", "Queries: the query scene's photos that the joint model holds in the map scene's model, with a "
           "reference pose in the map's frame. Left out: photos identical byte for byte to one of the map scene's "
           "(castle-P19 and castle-P30 share ten), and photos without a reference (unscored). Wrong: registered "
           "more than 5 m or 10° from the reference. The references carry the alignment's error (residuals above).\n",
           "| map <- queries | shared 3D points | queries | registered | median error (m) | wrong poses | "
           "identical photos left out | unscored |", "|---|---|---|---|---|---|---|---|"]
    for k, r in pairs.items():
        med = r.get("median_position_error_m")
        md.append(f"| {k} | {r['shared_points'] if r['shared_points'] is not None else 'not aligned'} | "
                  f"{r.get('queries', 0)} | {r.get('registered', 0)} | {'–' if med is None else f'{med:.3f}'} | "
                  f"{r.get('wrong_poses', 0)} | {r.get('identical_photos_left_out', 0)} | {r.get('unscored', 0)} |")
    ratios = [x for r in pairs.values() for x in r.get("error_over_sigma", [])]
    if ratios:
        md.append(f"\nRegistered: {sum(r.get('registered', 0) for r in pairs.values())} of "
                  f"{sum(r.get('queries', 0) for r in pairs.values())} queries; position error within 1σ for "
                  f"{np.mean(np.array(ratios) <= 1):.1%}, within 2σ for {np.mean(np.array(ratios) <= 2):.1%}.")
    md.append(f"\nTotal wrong poses: {sum(r.get('wrong_poses', 0) for r in pairs.values())}.\n")
    for k, r in pairs.items():
        for w in r.get("wrong", []):
            md.append(f"- {k}: {w['image']} {w['position_error_m']:.2f} m / {w['rotation_error_deg']:.2f}° off, "
                      f"{w['inliers']} inliers, confidence {w['confidence']:.3f}, σ "
                      f"{'–' if w['position_sigma'] is None else format(w['position_sigma'], '.3f')} m")
    (args.work / f"report-{args.focal}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
