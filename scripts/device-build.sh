#!/usr/bin/env bash
# visloc on a phone-class device: the runtime-only build (-DVISLOC_RUNTIME_ONLY=ON:
# the C API, the localizer and what it needs) cross-compiled for aarch64 and run
# under qemu-aarch64 (docs/device.md). Not part of CI: it downloads ~250 MB of
# Debian arm64 packages once.
#
#   scripts/device-build.sh               toolchain, sysroot, cross build, tests, example
#   scripts/device-build.sh --memory      ... then the memory study under qemu -R caps
#   scripts/device-build.sh --stage S     only one stage: toolchain|sysroot|build|test|pixels|example|memory
#
# Two aarch64 builds: build-aarch64 (runtime only, with its tests, decodes JPEG/PNG
# files) and build-aarch64-pixels (VISLOC_IMAGE_FILES=OFF: no OpenCV imgcodecs, the
# app passes camera pixels; the example reads PGM frames made from the photos).
#
# Environment:
#   VISLOC_SYSROOT   the arm64 sysroot (default ~/.cache/visloc/sysroot-arm64); created
#                    once, never touched by dpkg; present and complete = nothing downloaded
#   VISLOC_DEVICE_BUILD  cross build directory (default build-aarch64)
#   VISLOC_DEVICE_OUT    results: example outputs, memory tables (default build-aarch64/device-out)
#   VISLOC_DEVICE_MEMORY_MAPS  maps of the memory study (default "city castle-known")
#   VISLOC_DEVICE_MEMORY_VARIANTS  builds of the memory study (default "files pixels")
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)

SYSROOT=${VISLOC_SYSROOT:-${XDG_CACHE_HOME:-$HOME/.cache}/visloc/sysroot-arm64}
BUILD=${VISLOC_DEVICE_BUILD:-build-aarch64}
OUT=${VISLOC_DEVICE_OUT:-$BUILD/device-out}
HOST_BUILD=${VISLOC_HOST_BUILD:-build}
DATA=${VISLOC_SHARED_DATA_DIR:-$ROOT/../shared/data}
STAGES=(toolchain sysroot build test pixels example)
ONLY=""
while [ $# -gt 0 ]; do
  case "$1" in
    --memory) STAGES+=(memory) ;;
    --stage) [ $# -ge 2 ] || { echo "device-build: --stage needs a value (see --help)" >&2; exit 2; }
             ONLY="$2"; shift ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | grep '^#' | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "device-build: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
if [ -n "$ONLY" ]; then STAGES=("$ONLY"); fi

SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
log() { echo "device-build: $*"; }

# Debian arm64 packages the runtime build and its tests need (-dev packages pull
# their runtime libraries). calib3d only for the tests' baselines: the runtime
# library does not link it (the build stage checks). libopencv-dev for
# OpenCVConfig.cmake, which names every OpenCV module.
SYSROOT_PACKAGES=(
  libc6-dev libstdc++-12-dev libgomp1
  libopencv-core-dev libopencv-imgproc-dev libopencv-imgcodecs-dev
  libopencv-features2d-dev libopencv-calib3d-dev libopencv-dev
  libfaiss-dev libopenblas-dev libeigen3-dev libgeographiclib-dev libexiv2-dev
  nlohmann-json3-dev libgtest-dev
)

stage_toolchain() {
  local missing=()
  for p in crossbuild-essential-arm64 qemu-user cmake ninja-build time libjpeg-turbo-progs; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    log "installing ${missing[*]}"
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    log "toolchain present (aarch64-linux-gnu-g++ $(aarch64-linux-gnu-g++ -dumpversion), $(qemu-aarch64 --version | head -1))"
  fi
}

# Makes every absolute symlink under the sysroot relative, so that it resolves
# inside the sysroot and not on the host.
relativize_symlinks() {
  local root=$1
  find "$root" -type l -lname '/*' -print0 | while IFS= read -r -d '' link; do
    local target
    target=$(readlink "$link")
    ln -sfn "$(realpath -m --relative-to="$(dirname "$link")" "$root$target")" "$link"
  done
}

stage_sysroot() {
  local marker="$SYSROOT/.visloc-sysroot-complete" wanted="${SYSROOT_PACKAGES[*]}"
  if [ -f "$marker" ] && [ "$(cat "$marker")" = "$wanted" ]; then
    log "sysroot present: $SYSROOT ($(du -sh "$SYSROOT" | cut -f1)), nothing downloaded"
    return
  fi
  local work="$SYSROOT.partial" debs="$SYSROOT.debs"  # downloaded .debs, kept while the package list stays
  if [ -f "$marker" ]; then
    log "the package list changed: making the sysroot again"
    rm -rf "$debs"  # unpack nothing that the new list does not resolve to
  fi
  rm -rf "$work"
  mkdir -p "$debs/partial"
  mkdir -p "$work/state/lists/partial" "$work/cache" "$work/root"
  : > "$work/state/status"
  log "downloading ${#SYSROOT_PACKAGES[@]} arm64 packages and their dependencies (once, ~250 MB)"
  # apt with a state of its own (status, package lists, caches): the host's
  # apt lists and dpkg database are never read or written.
  local apt_opts=(-o "Dir::State=$work/state" -o "Dir::State::status=$work/state/status"
                  -o "Dir::State::Lists=$work/state/lists" -o "Dir::Cache=$work/cache"
                  -o "Dir::Cache::archives=$debs" -o APT::Architecture=arm64 -o "APT::Architectures::=arm64"
                  -o Debug::NoLocking=1 -o APT::Sandbox::User=root)
  apt-get "${apt_opts[@]}" update -qq
  apt-get "${apt_opts[@]}" -y -qq --no-install-recommends --download-only install "${SYSROOT_PACKAGES[@]}" >/dev/null
  local n
  n=$(ls "$debs"/*.deb | wc -l)
  log "unpacking $n packages ($(du -sh "$debs" | cut -f1))"
  for d in "$debs"/*.deb; do dpkg-deb -x "$d" "$work/root"; done
  relativize_symlinks "$work/root"
  local lib="$work/root/usr/lib/aarch64-linux-gnu"
  # BLAS/LAPACK are Debian alternatives (set up by dpkg, which never ran here).
  for name in blas lapack; do
    local impl="" candidate
    for candidate in "$lib/openblas-pthread/lib${name}.so.3" "$lib/${name}/lib${name}.so.3"; do
      if [ -e "$candidate" ]; then impl=$candidate; break; fi  # OpenBLAS first, as on the host
    done
    if [ -n "$impl" ]; then
      ln -sfn "$(realpath --relative-to="$lib" "$impl")" "$lib/lib${name}.so.3"
      ln -sfn "lib${name}.so.3" "$lib/lib${name}.so"
    fi
  done
  # ... and so is OpenBLAS's own library, which the OpenBLAS libblas.so.3 needs.
  if [ -e "$lib/openblas-pthread/libopenblas.so.0" ]; then
    ln -sfn openblas-pthread/libopenblas.so.0 "$lib/libopenblas.so.0"
  fi
  # FAISS's exported targets name absolute /usr/... paths: point them into the sysroot.
  local faiss_targets
  for faiss_targets in "$work"/root/usr/share/faiss/faiss-targets*.cmake "$work"/root/usr/lib/aarch64-linux-gnu/cmake/faiss/faiss-targets*.cmake; do
    [ -f "$faiss_targets" ] && sed -i "s#\([\";]\)/usr/#\1\${CMAKE_SYSROOT}/usr/#g" "$faiss_targets"
  done
  mv "$work/root" "$work/sysroot"
  rm -rf "$SYSROOT"
  mkdir -p "$(dirname "$SYSROOT")"
  mv "$work/sysroot" "$SYSROOT"
  rm -rf "$work"
  echo "$wanted" > "$marker"
  echo "$wanted" > "$debs/.visloc-package-list"
  log "sysroot ready: $SYSROOT ($(du -sh "$SYSROOT" | cut -f1))"
}

absolute() { case "$1" in /*) echo "$1" ;; *) echo "$ROOT/$1" ;; esac; }
HOST_CLI="$(absolute "$HOST_BUILD")/src/visloc/cli/visloc"
HOST_EXAMPLE="$(absolute "$HOST_BUILD")/examples/localize_photo"
DEVICE_EXAMPLE="$(absolute "$BUILD")/examples/localize_photo"
PIXELS_BUILD=${VISLOC_DEVICE_PIXELS_BUILD:-$BUILD-pixels}
PIXELS_EXAMPLE="$(absolute "$PIXELS_BUILD")/examples/localize_photo"
QEMU=(qemu-aarch64 -L "$SYSROOT")
need_host_build() {
  if [ ! -x "$HOST_CLI" ] || [ ! -x "$HOST_EXAMPLE" ]; then
    echo "device-build: the host build ($HOST_BUILD: visloc CLI, examples/localize_photo) is missing; run scripts/setup.sh first" >&2
    exit 1
  fi
}
need_sysroot() {
  if [ ! -f "$SYSROOT/.visloc-sysroot-complete" ]; then  # stage_sysroot writes it last
    echo "device-build: no sysroot at $SYSROOT; run scripts/device-build.sh --stage sysroot" >&2
    exit 1
  fi
}

# The shared libraries a file needs, transitively, resolved in the sysroot.
needed_closure() {
  local -A seen=()
  local queue=("$1") f lib path
  while [ ${#queue[@]} -gt 0 ]; do
    f=${queue[0]}; queue=("${queue[@]:1}")
    for lib in $(aarch64-linux-gnu-readelf -d "$f" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p'); do
      [ -n "${seen[$lib]:-}" ] && continue
      seen[$lib]=1
      path=""
      for dir in "$SYSROOT/usr/lib/aarch64-linux-gnu" "$SYSROOT/lib/aarch64-linux-gnu" "$SYSROOT/usr/lib/aarch64-linux-gnu/openblas-pthread"; do
        if [ -e "$dir/$lib" ]; then path=$(readlink -f "$dir/$lib"); break; fi
      done
      [ -n "$path" ] && queue+=("$path")
    done
  done
  printf '%s\n' "${!seen[@]}" | sort
}

stage_build() {
  need_sysroot
  need_host_build
  mkdir -p "$OUT"
  cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_TOOLCHAIN_FILE="$ROOT/cmake/aarch64-linux-gnu.cmake" -DVISLOC_SYSROOT="$SYSROOT" \
    -DVISLOC_RUNTIME_ONLY=ON -DVISLOC_HOST_CLI="$HOST_CLI" -DVISLOC_SHARED_DATA_DIR="$DATA" > "$OUT/configure.log" ||
    { cat "$OUT/configure.log" >&2; exit 1; }
  ninja -C "$BUILD"
  report_sizes "$BUILD" "$OUT/sizes.txt"
}

# report_sizes BUILD_DIR FILE: library and example sizes, exports, needed libraries.
report_sizes() {
  local build=$1 report=$2 lib example
  lib=$(readlink -f "$build/src/visloc/capi/libvisloc.so")
  example="$build/examples/localize_photo"
  aarch64-linux-gnu-strip -o "$report.libvisloc.stripped.so" "$lib"
  aarch64-linux-gnu-strip -o "$report.localize_photo.stripped" "$example"
  {
    echo "# aarch64 runtime build $build ($(date -u +%F), $(aarch64-linux-gnu-g++ -dumpfullversion), Release)"
    echo "libvisloc.so: $(stat -c %s "$lib") bytes, stripped $(stat -c %s "$report.libvisloc.stripped.so")"
    echo "localize_photo: $(stat -c %s "$example") bytes, stripped $(stat -c %s "$report.localize_photo.stripped")"
    echo "libvisloc.so exports: $(aarch64-linux-gnu-nm -D --defined-only "$lib" | awk '$2 == "T" {print $3}' | tr '\n' ' ')"
    echo "libvisloc.so needs directly: $(aarch64-linux-gnu-readelf -d "$lib" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p' | tr '\n' ' ')"
    local closure
    closure=$(needed_closure "$lib")
    echo "libvisloc.so needs in all, through Debian's builds of its dependencies ($(echo "$closure" | wc -l) libraries):"
    echo "$closure" | sed 's/^/  /'
    echo "of which each direct dependency brings (transitively):"
    local direct
    for direct in $(aarch64-linux-gnu-readelf -d "$lib" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p'); do
      local path
      path=$(readlink -f "$SYSROOT/usr/lib/aarch64-linux-gnu/$direct" 2>/dev/null || true)
      [ -f "$path" ] || path=$(readlink -f "$SYSROOT/lib/aarch64-linux-gnu/$direct" 2>/dev/null || true)
      [ -f "$path" ] && echo "  $direct: $(needed_closure "$path" | wc -l)"
    done
  } > "$report"
  cat "$report"
  # visloc's own link line: never calib3d, SQLite or CLI11 (Debian's OpenCV
  # imgcodecs pulls GDAL and, through it, SQLite: a device build of OpenCV
  # would leave GDAL out).
  if aarch64-linux-gnu-readelf -d "$lib" | grep NEEDED | grep -E 'opencv_calib3d|sqlite|CLI11'; then
    echo "device-build: libvisloc.so must not link calib3d, SQLite or CLI11" >&2
    exit 1
  fi
}

# The pixels build: no image files, no imgcodecs (what an app fed by a camera needs).
stage_pixels() {
  need_sysroot
  mkdir -p "$OUT"
  cmake -S . -B "$PIXELS_BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_TOOLCHAIN_FILE="$ROOT/cmake/aarch64-linux-gnu.cmake" -DVISLOC_SYSROOT="$SYSROOT" \
    -DVISLOC_RUNTIME_ONLY=ON -DVISLOC_IMAGE_FILES=OFF -DVISLOC_BUILD_TESTS=OFF > "$OUT/configure-pixels.log" ||
    { cat "$OUT/configure-pixels.log" >&2; exit 1; }
  ninja -C "$PIXELS_BUILD"
  report_sizes "$PIXELS_BUILD" "$OUT/sizes-pixels.txt"
  if aarch64-linux-gnu-readelf -d "$(readlink -f "$PIXELS_BUILD/src/visloc/capi/libvisloc.so")" | grep -q imgcodecs; then
    echo "device-build: the pixels build must not link OpenCV's imgcodecs" >&2
    exit 1
  fi
}

stage_test() {
  need_sysroot
  mkdir -p "$OUT"
  # Emulated code runs ~10-40x slower than native: generous timeouts.
  ctest --test-dir "$BUILD" --output-on-failure -j "$(nproc)" --timeout 1800 2>&1 | tee "$OUT/ctest.log"
}

# Maps the device runs against: the demo's synthetic city (scripts/demo.sh makes
# it) and castle-P30 imported with its held-out photos (from ../shared/data).
CITY_MAP="$ROOT/demo-out/city-map"
CITY_QUERIES="$ROOT/demo-out/city/queries"
CASTLE="$DATA/strecha/castle-P30"
CASTLE_MAP="$OUT/castle-map"
prepare_maps() {
  need_host_build
  mkdir -p "$OUT"
  if [ ! -f "$CITY_MAP/manifest.json" ]; then
    log "no demo city map at $CITY_MAP: running scripts/demo.sh first"
    scripts/demo.sh > "$OUT/demo.log" 2>&1 || { tail -20 "$OUT/demo.log" >&2; exit 1; }
  fi
  if [ -d "$CASTLE" ]; then
    # The true intrinsics (Strecha's K, pixel centres at integers) in visloc's
    # convention (top-left pixel centre at 0.5, 0.5), as an hloc query list.
    python3 - "$CASTLE" > "$OUT/castle-intrinsics.txt" <<'PY'
import pathlib, sys
for camera in sorted(pathlib.Path(sys.argv[1], "cameras").glob("*.camera")):
    v = camera.read_text().split()
    fx, cx, fy, cy, w, h = v[0], v[2], v[4], v[5], v[24], v[25]
    print(camera.name[:-len(".camera")], "PINHOLE", w, h, fx, fy, float(cx) + 0.5, float(cy) + 0.5)
PY
  fi
  if [ -d "$CASTLE" ] && [ ! -f "$CASTLE_MAP/manifest.json" ]; then
    log "importing castle-P30 with its held-out photos into $CASTLE_MAP"
    "$HOST_CLI" map import --colmap "$CASTLE/colmap/sparse" --database "$CASTLE/colmap/database.db" \
      --holdout "$CASTLE/queries.txt" --out "$CASTLE_MAP" --overwrite > "$OUT/castle-import.log"
  fi
}

# run_example ARCH MAP OUTFILE EXTRA... : localize_photo natively (x86-64) or under qemu.
run_example() {
  local arch=$1 map=$2 out=$3; shift 3
  local status=0
  if [ "$arch" = host ]; then
    "$HOST_EXAMPLE" "$map" "$@" > "$out" || status=$?
  else
    timeout 3600 "${QEMU[@]}" "$DEVICE_EXAMPLE" "$map" "$@" > "$out" || status=$?
  fi
  # exit 1: a call failed for some photo (its line says which); compared below
  if [ "$status" != 0 ] && [ "$status" != 1 ]; then
    echo "device-build: localize_photo ($arch) exited with $status" >&2
    exit 1
  fi
}

example_args() {  # MAP_NAME → the photos and options of that map's queries
  case "$1" in
    city) echo "--intrinsics $CITY_QUERIES/intrinsics.txt --max-side 1024"
          head -12 "$CITY_QUERIES/list.txt" | sed "s#^#$CITY_QUERIES/images/#" ;;
    castle) echo "--max-side 1024"  # no intrinsics: the focal length is estimated
            sed "s#^#$CASTLE/images/#" "$CASTLE/queries.txt" ;;
    castle-known) echo "--intrinsics $OUT/castle-intrinsics.txt --max-side 1024"
                  sed "s#^#$CASTLE/images/#" "$CASTLE/queries.txt" ;;
  esac
}

# pgm_args NAME: example_args with every photo turned into an 8-bit PGM frame
# (djpeg -grayscale: the luma plane, as OpenCV's greyscale decoding gives it) and
# an intrinsics list that names the frames.
pgm_args() {
  local dir="$OUT/frames/$1" a
  mkdir -p "$dir"
  local next_is_list=0
  for a in $(example_args "$1"); do
    if [ "$next_is_list" = 1 ]; then
      sed 's/^\([^ .]*\)\.[A-Za-z]* /\1.pgm /' "$a" > "$dir/intrinsics.txt"
      echo "$dir/intrinsics.txt"
      next_is_list=0
    elif [ "$a" = --intrinsics ]; then
      echo "$a"; next_is_list=1
    elif [ -f "$a" ] && [[ "$a" == *.jpg ]]; then
      local frame
      frame="$dir/$(basename "${a%.*}").pgm"
      [ -f "$frame" ] || djpeg -grayscale -pnm -outfile "$frame" "$a"
      echo "$frame"
    else
      echo "$a"
    fi
  done
}

stage_example() {
  need_sysroot
  prepare_maps
  local name map
  for name in city castle castle-known; do
    map=$CITY_MAP; [[ "$name" == castle* ]] && map=$CASTLE_MAP
    [ -f "$map/manifest.json" ] || { log "no $name map: skipped"; continue; }
    mapfile -t args < <(example_args "$name" | tr ' ' '\n' | grep -v '^$')
    log "$name: localize_photo on x86-64 and on aarch64 (qemu), ${#args[@]} arguments"
    run_example host "$map" "$OUT/$name.x86_64.jsonl" "${args[@]}"
    run_example device "$map" "$OUT/$name.aarch64.jsonl" "${args[@]}"
    python3 scripts/compare_poses.py "$OUT/$name.x86_64.jsonl" "$OUT/$name.aarch64.jsonl" > "$OUT/$name.compare.txt" ||
      log "$name: x86-64 and aarch64 disagree (docs/device.md explains the known cause)"
    cat "$OUT/$name.compare.txt"
    if [ -x "$PIXELS_EXAMPLE" ]; then
      mapfile -t args < <(pgm_args "$name")
      log "$name: the pixels build on aarch64, photos passed as PGM frames"
      local status=0
      timeout 3600 "${QEMU[@]}" "$PIXELS_EXAMPLE" "$map" "${args[@]}" > "$OUT/$name.aarch64-pixels.jsonl" || status=$?
      [ "$status" -le 1 ] || { echo "device-build: localize_photo (pixels) exited with $status" >&2; exit 1; }
      python3 scripts/compare_poses.py "$OUT/$name.aarch64.jsonl" "$OUT/$name.aarch64-pixels.jsonl" \
        > "$OUT/$name.compare-pixels.txt" || log "$name: files and pixels disagree on aarch64"
      tail -1 "$OUT/$name.compare-pixels.txt"
    fi
  done
}

# peak_kib LOG: qemu's peak resident set from /usr/bin/time -v (guest pages + ~20 MB of qemu).
peak_kib() { local v; v=$(sed -n 's/.*Maximum resident set size (kbytes): //p' "$1" 2>/dev/null); echo "${v:-0}"; }

# first_photo_and_options NAME [pixels]: sets options=(...) and photo for a map's first query.
first_photo_and_options() {
  local a
  options=(); photo=""
  if [ "${2:-}" = pixels ]; then
    mapfile -t args < <(pgm_args "$1")
  else
    mapfile -t args < <(example_args "$1" | tr ' ' '\n' | grep -v '^$')
  fi
  for a in "${args[@]}"; do
    if [ -f "$a" ] && [[ "$a" == *.jpg || "$a" == *.png || "$a" == *.pgm ]]; then
      if [ -z "$photo" ]; then photo=$a; fi
    else
      options+=("$a")
    fi
  done
}

# registers_within CAP_MIB LOG ARGS...: localize_photo under qemu -R CAP; 0 when the photo registers.
registers_within() {
  local cap=$1 log=$2; shift 2
  timeout 3600 env OMP_NUM_THREADS="${DEVICE_OMP_THREADS:-$(nproc)}" \
    qemu-aarch64 -R "${cap}M" -L "$SYSROOT" "$example" "$@" > "$log" 2>&1 &&
    grep -q '"registered": 1' "$log"
}

# The memory study: peak memory per stage, and the smallest address-space cap
# (qemu -R, 16 MiB steps) at which the first query photo still registers, per
# configuration (photo size, threads).
stage_memory() {
  need_sysroot
  prepare_maps
  local name map table variant example configs
  for name in ${VISLOC_DEVICE_MEMORY_MAPS:-city castle-known}; do
   for variant in ${VISLOC_DEVICE_MEMORY_VARIANTS:-files pixels}; do
    if [ "$variant" = pixels ]; then
      example=$PIXELS_EXAMPLE
      configs=("pixels, 1024 px, 1 thread:--max-side 1024 --threads 1:1" "pixels, 800 px, 1 thread:--max-side 800 --threads 1:1"
               "pixels, 640 px, 1 thread:--max-side 640 --threads 1:1")
    else
      example=$DEVICE_EXAMPLE
      configs=("1024 px, 2 threads:--max-side 1024 --threads 2:2" "1024 px, 1 thread:--max-side 1024 --threads 1:1"
               "800 px, 1 thread:--max-side 800 --threads 1:1" "640 px, 1 thread:--max-side 640 --threads 1:1")
    fi
    [ -x "$example" ] || { log "no $variant build ($example): skipped"; continue; }
    table="$OUT/memory-$name-$variant.md"
    {
      echo "| map | configuration | run | peak RSS under qemu (MiB) | registered | inliers | features |"
      echo "|---|---|---|---|---|---|---|"
    } > "$table"
    map=$CITY_MAP; [[ "$name" == castle* ]] && map=$CASTLE_MAP
    [ -f "$map/manifest.json" ] || { log "no $name map: skipped"; continue; }
    first_photo_and_options "$name" "$variant"
    local config
    for config in "${configs[@]}"; do
      local label=${config%%:*} rest=${config#*:}
      local config_options threads=${rest##*:}
      read -r -a config_options <<< "${rest%:*}"
      # drop the map's own --max-side: the configuration sets it
      local base=() i=0
      while [ $i -lt ${#options[@]} ]; do
        if [ "${options[$i]}" = --max-side ]; then i=$((i + 2)); continue; fi
        base+=("${options[$i]}"); i=$((i + 1))
      done
      local run extra tag
      for run in "open:--open-only" "query:"; do
        read -r -a extra <<< "${run#*:}"
        tag="$name-${label//[ ,]/_}-${run%%:*}"
        /usr/bin/time -v -o "$OUT/mem-$tag.time" timeout 3600 env OMP_NUM_THREADS="$threads" "${QEMU[@]}" \
          "$example" "$map" "${base[@]}" "${config_options[@]}" ${extra[@]+"${extra[@]}"} "$photo" \
          > "$OUT/mem-$tag.jsonl" 2>&1 || true
        local fields
        fields=$(python3 - "$OUT/mem-$tag.jsonl" <<'PY'
import json, sys
try:
    rows = [json.loads(l) for l in open(sys.argv[1]) if l.startswith('{"image')]
except ValueError:
    rows = []
r = rows[0] if rows else {}
print(r.get("registered", "-"), r.get("inliers", "-"), r.get("features", "-"))
PY
) || fields="- - -"
        read -r reg inl feat <<< "$fields"
        echo "| $name | $label | ${run%%:*} | $(( $(peak_kib "$OUT/mem-$tag.time") / 1024 )) | $reg | $inl | $feat |" | tee -a "$table"
      done
      # Bisection over caps in 16 MiB steps between 64 MiB and 1024 MiB.
      local lo=64 hi=1024 mid
      if ! DEVICE_OMP_THREADS=$threads registers_within $hi "$OUT/cap-$tag-$hi.log" "$map" "${base[@]}" "${config_options[@]}" "$photo"; then
        echo "| $name | $label | smallest -R cap that registers | none up to $hi MiB | | | |" | tee -a "$table"
        continue
      fi
      if DEVICE_OMP_THREADS=$threads registers_within $lo "$OUT/cap-$tag-$lo.log" "$map" "${base[@]}" "${config_options[@]}" "$photo"; then
        hi=$lo
      fi
      while [ $((hi - lo)) -gt 16 ]; do
        mid=$(( (lo + hi) / 2 / 16 * 16 ))
        if DEVICE_OMP_THREADS=$threads registers_within $mid "$OUT/cap-$tag-$mid.log" "$map" "${base[@]}" "${config_options[@]}" "$photo"; then
          hi=$mid
        else
          lo=$mid
        fi
      done
      echo "| $name | $label | smallest -R cap that registers (16 MiB steps) | $hi MiB | | | |" | tee -a "$table"
    done
   done
  done
  log "memory tables: $OUT/memory-*.md"
}

for stage in "${STAGES[@]}"; do
  case "$stage" in
    toolchain) stage_toolchain ;;
    sysroot) stage_sysroot ;;
    *) if declare -F "stage_$stage" >/dev/null; then "stage_$stage"; else
         echo "device-build: unknown stage '$stage'" >&2; exit 2; fi ;;
  esac
done
