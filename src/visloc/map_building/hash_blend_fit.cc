#include "visloc/map_building/hash_blend_fit.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/map/map.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace fs = std::filesystem;

namespace visloc {

void MapBlendFitOptions::validate() const {
  if (views < 2 || views > 100000)
    throw_error(ErrorCode::kInvalidArgument, "MapBlendFitOptions.views must be in [2, 100000], got ", views);
  fit.validate();
}

namespace {

bool is_model_dir(const fs::path& dir) {
  std::error_code ec;
  return fs::exists(dir / "points3D.bin", ec) || fs::exists(dir / "points3D.txt", ec);
}

// A segment's views and distractors. The views are searched in rounds, each
// in a copy of the index where only that round's points are re-encoded
// (hash and PQ codes, lookup rebuilt) from their track's mean without their
// view: at most a twentieth of the segment's points per round, so that the
// other points stand as the map has them. The distractors are searched in
// the segment's own index.
HammingBlendFit fit_segment(const Map& map, const Segment& segment, const DescriptorMatrix& stored,
                            const PointDescriptors& desc, const HammingBlendFitOptions& options) {
  const CascadeIndexView& index = segment.index();
  const size_t n = segment.num_points();
  DescriptorMatrix views(desc.sampled_points.size()), distractors(desc.sampled_points.size());
  std::vector<uint32_t> view_points;
  std::vector<float> others(desc.sampled_points.size() * kDescriptorDim);
  for (size_t k = 0; k < desc.sampled_points.size(); ++k) {
    const uint32_t p = desc.sampled_points[k];
    std::copy_n(stored.row(p), kDescriptorDim, distractors.row(k));
    if (!leave_one_out_mean(desc.mean.data() + size_t(p) * kDescriptorDim, desc.sampled_observations.row(k),
                            desc.track_size[p], others.data() + view_points.size() * kDescriptorDim))
      continue;
    std::copy_n(desc.sampled_observations.row(k), kDescriptorDim, views.row(view_points.size()));
    view_points.push_back(p);
  }
  const size_t nv = view_points.size();
  std::vector<HashCode> other_codes(nv);
  const size_t code_bytes = size_t(index.pq_subvectors);
  std::vector<uint8_t> other_pq(nv * code_bytes);
  if (nv > 0) {
    HashWorkspace hash_ws;
    encode_hash(index.hasher, others.data(), nv, other_codes.data(), hash_ws);
    map.codebook().encode(others.data(), nv, other_pq.data());
  }
  // The distractors (no view) in the segment's own index.
  HammingBlendFit sum =
      fit_hamming_blend(index, map.codebook(), DescriptorMatrix(), {}, options, &distractors, desc.sampled_points);
  std::vector<HashCode> codes(index.codes, index.codes + n);
  std::vector<uint8_t> pq(index.pq_codes, index.pq_codes + n * code_bytes);
  const size_t per_round = std::max<size_t>(1, n / 20);
  for (size_t begin = 0; begin < nv; begin += per_round) {
    const size_t end = std::min(nv, begin + per_round);
    for (size_t k = begin; k < end; ++k) {
      codes[view_points[k]] = other_codes[k];
      std::copy_n(other_pq.data() + k * code_bytes, code_bytes, pq.data() + size_t(view_points[k]) * code_bytes);
    }
    const CascadeLookup lookup(codes, /*neighbourhood_sizes=*/false);  // the fit's search is not prioritized
    CascadeIndexView held_out = index;
    held_out.codes = codes.data();
    held_out.pq_codes = pq.data();
    held_out.lookup = &lookup;
    const DescriptorMatrix round_views(views.row(begin), end - begin);
    const std::span<const uint32_t> round_points(view_points.data() + begin, end - begin);
    const HammingBlendFit round = fit_hamming_blend(held_out, map.codebook(), round_views, round_points, options);
    sum.queries += round.queries;
    sum.listed += round.listed;
    for (size_t s = 0; s < sum.correct.size(); ++s) sum.correct[s] += round.correct[s], sum.wrong[s] += round.wrong[s];
    for (size_t k = begin; k < end; ++k) {  // restore the map's codes
      const uint32_t p = view_points[k];
      codes[p] = index.codes[p];
      std::copy_n(index.pq_codes + size_t(p) * code_bytes, code_bytes, pq.data() + size_t(p) * code_bytes);
    }
  }
  choose_hamming_blend_weight(sum);
  return sum;
}

}  // namespace

MapBlendFit fit_map_hash_blend(const fs::path& map_dir, const MapBlendFitOptions& options) {
  options.validate();
  Timer timer;
  const Map map = Map::open(map_dir);
  const MapManifest& man = map.manifest();
  const std::string where = map_dir.string();
  const auto text_of = [&man](const char* key) {
    const auto it = man.source.is_object() ? man.source.find(key) : man.source.end();
    return it != man.source.end() && it->is_string() ? it->get<std::string>() : std::string();
  };
  const std::string type = text_of("type");
  MapBlendFit out;
  out.weight_steps = options.fit.weight_steps;
  const bool imported = type == "colmap" && !text_of("model").empty() && !text_of("database").empty();
  if (!imported && type != "build")
    throw_error(ErrorCode::kInvalidArgument, where,
                ": fitting the hash blend needs a map imported from a COLMAP model and database (map import "
                "--colmap) or built by map build; this map's source is ",
                type.empty() ? std::string("not recorded") : "'" + type + "'");
  if (imported && man.segments.size() != 1)
    throw_error(ErrorCode::kInvalidArgument, where, ": an imported map has one segment; this one has ",
                man.segments.size());
  if (man.segments.empty()) throw_error(ErrorCode::kInvalidArgument, where, ": the map has no segments");
  for (const auto& s : man.segments) {
    out.points += s.points;
    out.segment_crc32c.push_back(s.file_crc32c);
  }

  std::vector<HammingBlendFit> fits;
  for (size_t si = 0; si < man.segments.size(); ++si) {
    const MapSegmentEntry& entry = man.segments[si];
    if (entry.descriptors_file.empty())
      throw_error(ErrorCode::kInvalidArgument, where, ": segment ", entry.id,
                  " kept no point descriptors (imported with --no-descriptors); fitting the hash blend checks "
                  "them against its model's");
    MapBlendFit::SegmentSource src;
    src.segment = int(entry.id);
    std::vector<fs::path> candidates;
    if (imported) {
      src.model = text_of("model");
      src.database = text_of("database");
      candidates.push_back(src.model);
    } else {
      const fs::path work = segment_work_dir(map_dir, int(entry.id));
      src.database = (work / "database.db").string();
      std::error_code ec;
      if (fs::is_directory(work / "sparse", ec))
        for (const auto& d : fs::directory_iterator(work / "sparse", ec))
          if (is_model_dir(d.path())) candidates.push_back(d.path());
      std::sort(candidates.begin(), candidates.end());
      if (candidates.empty() || !fs::exists(src.database, ec))
        throw_error(ErrorCode::kInvalidArgument, where, ": segment ", entry.id, "'s COLMAP model and database ",
                    "are not in ", work.string(), " (map build keeps them there: was it removed?)");
    }
    const std::unique_ptr<Segment> segment = map.open_segment(si);
    const DescriptorMatrix stored = read_point_descriptor_file(fs::path(map_dir) / entry.descriptors_file);
    if (stored.rows() != segment->num_points())
      throw_error(ErrorCode::kFormat, where, ": segment ", entry.id, "'s descriptor file holds ", stored.rows(),
                  " points, the segment ", segment->num_points());
    // The segment's share of the views, by its points.
    const size_t share =
        std::max<size_t>(2, size_t(double(options.views) * double(segment->num_points()) / double(out.points)));
    std::unique_ptr<ColmapDatabase> db;
    try {
      db = std::make_unique<ColmapDatabase>(src.database);
    } catch (const Error& e) {
      throw_error(e.code(), where, ": opening segment ", entry.id, "'s database ", src.database,
                  " (recorded when the map was made): ", e.what());
    }
    std::string reasons;  // why each candidate model was not the segment's
    bool found = false;
    for (const fs::path& dir : candidates) {
      try {
        ColmapModel model = read_colmap_model(dir);
        if (imported && !man.holdout_images.empty()) remove_images(model, man.holdout_images);
        if (model.points.size() != segment->num_points()) {
          reasons += "; " + dir.string() + " has " + std::to_string(model.points.size()) + " points, the segment " +
                     std::to_string(segment->num_points());
          continue;
        }
        const PointDescriptors desc = compute_point_descriptors(model, *db, share);
        const DescriptorMatrix means = round_descriptors(desc.mean);
        if (!std::equal(means.data(), means.data() + means.size_bytes(), stored.data())) {
          reasons += "; the track means of " + dir.string() + " and " + src.database +
                     " are not the segment's point descriptors";
          continue;
        }
        src.model = dir.string();
        src.points = segment->num_points();
        fits.push_back(fit_segment(map, *segment, stored, desc, options.fit));
      } catch (const Error& e) {
        reasons += "; " + dir.string() + ": " + e.what();
        continue;
      }
      src.views = fits.back().queries;
      found = true;
      break;
    }
    if (!found)
      throw_error(ErrorCode::kFormat, where, ": segment ", entry.id,
                  ": no model matches its points (the model or database changed since the map was made)", reasons);
    out.segments.push_back(src);
  }
  out.ms = timer.elapsed_ms();
  // The sum over the segments, and its weight.
  HammingBlendFit& sum = out.fit;
  const size_t steps = size_t(options.fit.weight_steps);
  sum.correct.assign(steps + 1, 0);
  sum.wrong.assign(steps + 1, 0);
  sum.distractor_matched.assign(steps + 1, 0);
  for (const HammingBlendFit& f : fits) {
    sum.queries += f.queries;
    sum.listed += f.listed;
    sum.distractors += f.distractors;
    for (size_t k = 0; k <= steps; ++k) {
      sum.correct[k] += f.correct[k];
      sum.wrong[k] += f.wrong[k];
      sum.distractor_matched[k] += f.distractor_matched[k];
    }
  }
  choose_hamming_blend_weight(sum);
  if (sum.queries == 0)
    throw_error(ErrorCode::kInvalidArgument, where, ": no point has a track of 2 views or more to fit on");
  return out;
}

void store_map_hash_blend(const fs::path& map_dir, const MapBlendFit& fit, bool lock_build) {
  // A running build (map build or map update) holds MAP/work/build.lock.
  int lock_fd = -1;
  const fs::path lock_path = map_dir / "work" / "build.lock";
  if (lock_build) {
    lock_fd = ::open(lock_path.c_str(), O_RDONLY | O_CLOEXEC);  // flock needs no write access
    if (lock_fd < 0 && errno != ENOENT && errno != ENOTDIR)     // absent: the map was never built here
      throw_error(ErrorCode::kIo, lock_path.string(), ": cannot open the build lock: ", std::strerror(errno));
    if (lock_fd >= 0 && ::flock(lock_fd, LOCK_EX | LOCK_NB) != 0) {
      ::close(lock_fd);
      throw_error(ErrorCode::kInvalidArgument, map_dir.string(),
                  ": a build of the map (or another store) is running; store the hash blend after it ends (fit "
                  "again then)");
    }
  }
  struct Unlock {
    int fd;
    ~Unlock() {
      if (fd >= 0) ::close(fd);
    }
  } unlock{lock_fd};
  MapManifest man = read_manifest(map_dir);
  std::vector<uint32_t> now;
  for (const auto& s : man.segments) now.push_back(s.file_crc32c);
  if (now != fit.segment_crc32c)
    throw_error(ErrorCode::kInvalidArgument, map_dir.string(),
                ": the map's segments changed after the hash blend was fitted (was it rebuilt meanwhile?); not "
                "stored: fit again");
  nlohmann::json summary = fit.to_json();
  // The manifest records what was fitted, not how fast nor where its sources
  // lie (a built map's are in its own work folder, wherever the map is).
  summary.erase("ms");
  for (auto& segment : summary["segments"]) {
    segment.erase("model");
    segment.erase("database");
  }
  summary["weight_steps"] = fit.weight_steps;
  man.hash_blend = MapHashBlend{fit.fit.weight, fit.segment_crc32c, std::move(summary)};
  write_manifest(map_dir, man);
}

nlohmann::json MapBlendFit::to_json() const {
  nlohmann::json grid = nlohmann::json::array();
  for (size_t k = 0; k < fit.correct.size(); ++k)
    grid.push_back({{"weight", double(k) / weight_steps},
                    {"views_right", fit.correct[k]},
                    {"views_wrong", fit.wrong[k]},
                    {"distractors_matched", fit.distractor_matched[k]}});
  nlohmann::json sources = nlohmann::json::array();
  for (const auto& s : segments)
    sources.push_back({{"segment", s.segment},
                       {"model", s.model},
                       {"database", s.database},
                       {"points", s.points},
                       {"views", s.views}});
  return {{"weight", fit.weight},
          {"views", fit.queries},
          {"views_listed", fit.listed},
          {"distractors", fit.distractors},
          {"points", points},
          {"segments", sources},
          {"ms", ms},
          {"grid", grid}};
}

std::string MapBlendFit::summary(const std::string& map_dir) const {
  std::ostringstream s;
  s << map_dir << ": hash blend weight " << fit.weight << "\n"
    << "  " << fit.queries << " held-out views of the " << points << " points of " << segments.size()
    << (segments.size() == 1 ? " segment (" : " segments (") << fit.listed << " with a short list), " << fit.distractors
    << " distractors; " << std::fixed << std::setprecision(0) << ms << " ms\n"
    << "  weight  views right  views wrong  distractors matched  net\n";
  for (size_t k = 0; k < fit.correct.size(); ++k) {
    const double w = double(k) / weight_steps;
    s << "  " << std::setw(6) << std::setprecision(2) << w << std::setprecision(0) << std::setw(13) << fit.correct[k]
      << std::setw(13) << fit.wrong[k] << std::setw(21) << fit.distractor_matched[k] << std::setw(5)
      << (long(fit.correct[k]) - long(fit.wrong[k]) - long(fit.distractor_matched[k]))
      << (w == fit.weight ? "  <- chosen" : "") << "\n";
  }
  return s.str();
}

}  // namespace visloc
