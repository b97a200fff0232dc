// The localizer's options as command-line options (util/option_table.h).
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/option_table.h"

namespace visloc {

void add_options(OptionTable& t, LocalizerOptions& o) {
  t.choice("--setting", o.setting,
           {{"1", PaperSetting::k1}, {"2", PaperSetting::k2}, {"3", PaperSetting::k3}, {"3+", PaperSetting::k3Plus}},
           "The paper's ablation setting: 1, 2, 3 or 3+");
  t.add("--top-images", o.top_images, "Retrieval: images N_t");
  t.add("--max-segments", o.max_segments, "Candidate segments searched first");
  t.add("--fallback-segments", o.fallback_segments,
        "When the first --max-segments candidates give no registered pose, search this many more, the next by votes "
        "(0: none)");
  t.choice("--segment-votes", o.segment_votes,
           {{"auto", SegmentVoteSource::kAuto},
            {"images", SegmentVoteSource::kImages},
            {"points", SegmentVoteSource::kPoints},
            {"both", SegmentVoteSource::kBoth}},
           "What ranks the candidate segments on a map of more than --max-segments segments: 'points' "
           "(each query feature votes for the segment of its nearest map point by hash code; needs a map "
           "with one hash rotation, map build's default), 'images' (the retrieved images' votes, the "
           "paper's), 'both' (the sum of the two vote shares; needs both) or 'auto' (points, the "
           "retrieved images filling the places they leave; images alone on a map with a rotation per "
           "segment)");
  t.add("--vote-points", o.point_votes.points_per_segment,
        "Point votes: points indexed per segment at most (0: all; each costs ~65 bytes of memory)")
      .range(0, 1 << 28);
  t.add("--vote-max-points", o.point_votes.max_points,
        "Point votes: points indexed over the whole map at most; a map of more indexes each segment's share, "
        "evenly strided (0: no bound)")
      .range(0, 1 << 28);
  t.add("--vote-radius", o.point_votes.probe_radius,
        "Point votes: lookup-table buckets probed per table: the feature's 16-bit sub-code (0) and also "
        "those 1 bit off it (1, the default: up to 17 buckets, only when radius 0 found no point within 7 bits or "
        "skipped an overfull bucket; finds matches that differ in more bits; its buckets are skipped above a "
        "sixteenth of the bucket bound)")
      .range(0, 1);
  t.add("--vote-ratio", o.point_votes.distinct_ratio,
        "Point votes: a feature votes only when its nearest map point is nearer (Hamming bits) than this "
        "times the nearest point of any segment that shares no image with that point's (Lowe's ratio test "
        "across segments: a facade that looks like other streets' does not vote); 1: every feature votes")
      .range(0.01, 1.0);
  t.flag("--vote-chance-normalization", o.point_votes.normalize_by_chance,
         "Point votes: divide each segment's votes by its rate of chance votes from unrelated segments' points");
  t.add("--accept-inliers", o.accept_inliers,
        "Stop searching further candidate segments once a pose has this many inliers (0: search all)");
  t.add("--lut-flips", o.search.lut_flips,
        "Cascade search (every setting): of a lookup table's 16 buckets one bit off the query's, probe all (16) "
        "or the N whose bits' projections lie nearest their hyperplanes (query-directed probing: fewer candidates, "
        "a faster full search, but a weaker ratio test: slightly fewer right matches first)")
      .range(0, 16);
  t.add("--lut-flips-min-list", o.search.lut_flips_min_list,
        "With --lut-flips below 16: probe --lut-flips neighbours only for the features whose radius-1 coarse "
        "list (the sum of their 136 buckets' sizes) holds more than this many points; the others probe all 16 "
        "(0: every feature)")
      .range(0, 1 << 30);
  t.text(
      "--hash-blend", hash_blend_text(o),
      [&o](const std::string& text) {
        try {
          o.hash_blend_source = parse_hash_blend(text, o.search.hash_blend_weight);
        } catch (const Error& e) {
          throw_error(e.code(), "--hash-blend: ", e.what());
        }
      },
      "Cascade search (every setting): weight w in [0, 1] of the distance the 128-bit hash codes imply, blended "
      "into the PQ distance that ranks each short list: (1 - w) d2_PQ + w d2_hash; 'map': the weight fitted on "
      "the map and stored in it (map build and COLMAP imports store one as they finish; `visloc map fit-blend "
      "--store`), 0 on a map without one or whose segments changed since. 0: the PQ alone (the paper's); > 0: more "
      "right matches, but a smaller share of them right");
  t.add("--early-stop", o.search.early_stop,
        "Settings 3, 3+: the prioritized search stops at this many 1-1 matches (N_early)");
  t.flag("!--no-fallback", o.full_search_fallback,
         "Settings 3, 3+: do not search all features again when the prioritized search fails (of the same "
         "segments; --fallback-segments is another fallback)");
  t.add("--threshold", o.ransac.threshold_px, "RANSAC reprojection threshold (px)");
  t.add("--min-inliers", o.ransac.min_inliers, "Registered at this many inliers");
  t.add("--min-confidence", o.min_confidence,
        "... and at this confidence in [0, 1] (the builtin model's probability that the pose is right; "
        "the default is chosen for a precision of 99.5%; 0: inliers only, the paper's rule)")
      .range(0.0, 1.0);
  t.flag("!--no-map-point-uncertainty", o.map_point_uncertainty,
         "Leave the map points' triangulation uncertainty (maps built since it is stored) out of a pose's "
         "reported sigma: the sigma of the photo's keypoint noise alone");
  t.flag("!--allow-under-street", o.under_street.enabled,
         "Register a pose even when its camera stands under the street (geo-registered maps: more than "
         "--max-drop-below-map m, plus 0.35 m per metre of plan distance, below the nearest map camera, and "
         "more than 1 m below the ground the map's points give within 30 m)");
  t.add("--max-drop-below-map", o.under_street.max_drop_m,
        "Metres a camera may stand below the nearest map camera (beyond the slope) before it counts as under "
        "the street")
      .range(0.0, 1e6);
  t.flag("!--no-exif-focal", o.use_exif_focal, "Ignore EXIF focal lengths");
  add_options(t, o.sift);
  t.text("--cache-mib", std::to_string(o.cache_bytes >> 20),
         [&o](const std::string& text) {
           const double mib = parse_finite_number(text, "--cache-mib", 1, 1 << 30);
           o.cache_bytes = static_cast<uint64_t>(mib * 1024 * 1024);
         },
         "Segment cache budget (MiB)");
}

}  // namespace visloc
