#include "visloc/map_building/hash_blend_fit.h"

#include <algorithm>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/map/map.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

void MapBlendFitOptions::validate() const {
  if (views < 2 || views > (size_t(1) << 24))
    throw_error(ErrorCode::kInvalidArgument, "MapBlendFitOptions.views must be in [2, 16777216], got ", views);
  fit.validate();
}

MapBlendFit fit_map_hash_blend(const std::filesystem::path& map_dir, const MapBlendFitOptions& options) {
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
  out.model = text_of("model");
  out.database = text_of("database");
  if (type != "colmap" || out.model.empty() || out.database.empty())
    throw_error(ErrorCode::kInvalidArgument, where,
                ": fitting the hash blend needs a map imported from a COLMAP model and database (map import "
                "--colmap); this map's source is ",
                type.empty() ? std::string("not recorded") : "'" + type + "'");
  if (man.segments.size() != 1)
    throw_error(ErrorCode::kInvalidArgument, where, ": fitting the hash blend needs a one-segment map; it has ",
                man.segments.size());
  if (man.segments[0].descriptors_file.empty())
    throw_error(ErrorCode::kInvalidArgument, where,
                ": the map kept no point descriptors (imported with --no-descriptors); fitting the hash blend "
                "checks them against the model's");
  const std::unique_ptr<Segment> segment = map.open_segment(0);
  const DescriptorMatrix stored =
      read_point_descriptor_file(std::filesystem::path(map_dir) / man.segments[0].descriptors_file);
  ColmapModel model = read_colmap_model(out.model);
  try {
    if (!man.holdout_images.empty()) remove_images(model, man.holdout_images);
  } catch (const Error& e) {
    throw_error(ErrorCode::kFormat, where, ": the map's held-out images are not in ", out.model,
                " (the model changed since the import?): ", e.what());
  }
  const ColmapDatabase db(out.database);
  const PointDescriptors desc = compute_point_descriptors(model, db, options.views);
  out.points = segment->num_points();
  if (stored.rows() != out.points)
    throw_error(ErrorCode::kFormat, where, ": its descriptor file holds ", stored.rows(), " points, its segment ",
                out.points);
  const DescriptorMatrix means = round_descriptors(desc.mean);
  if (means.rows() != out.points)
    throw_error(ErrorCode::kFormat, where, ": ", out.model, " has ", means.rows(),
                " points (its held-out images "
                "removed), the map ",
                out.points, ": the model changed since the import");
  if (!std::equal(means.data(), means.data() + means.size_bytes(), stored.data()))
    throw_error(ErrorCode::kFormat, where, ": the track means of ", out.model, " and ", out.database,
                " are not the map's point descriptors: model or database changed since the import");
  // The views: each sampled point's observation, searched in a copy of the
  // index where that point is re-encoded (hash and PQ codes, lookup rebuilt)
  // from its track's mean without the observation.
  const CascadeIndexView& index = segment->index();
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
  views.resize(view_points.size());
  if (view_points.empty())
    throw_error(ErrorCode::kInvalidArgument, where, ": no point has a track of 2 views or more to fit on");
  const size_t nv = view_points.size();
  std::vector<HashCode> codes(index.codes, index.codes + out.points), other_codes(nv);
  const size_t code_bytes = size_t(index.pq_subvectors);
  std::vector<uint8_t> pq(index.pq_codes, index.pq_codes + out.points * code_bytes), other_pq(nv * code_bytes);
  HashWorkspace hash_ws;
  encode_hash(index.hasher, others.data(), nv, other_codes.data(), hash_ws);
  map.codebook().encode(others.data(), nv, other_pq.data());
  for (size_t k = 0; k < nv; ++k) {
    codes[view_points[k]] = other_codes[k];
    std::copy_n(other_pq.data() + k * code_bytes, code_bytes, pq.data() + size_t(view_points[k]) * code_bytes);
  }
  const CascadeLookup lookup(codes);
  CascadeIndexView held_out = index;
  held_out.codes = codes.data();
  held_out.pq_codes = pq.data();
  held_out.lookup = &lookup;
  out.ms_read = timer.elapsed_ms();
  timer.reset();
  out.fit =
      fit_hamming_blend(held_out, map.codebook(), views, view_points, options.fit, &distractors, desc.sampled_points);
  out.ms_fit = timer.elapsed_ms();
  return out;
}

nlohmann::json MapBlendFit::to_json() const {
  nlohmann::json grid = nlohmann::json::array();
  for (size_t k = 0; k < fit.correct.size(); ++k)
    grid.push_back({{"weight", double(k) / weight_steps},
                    {"views_right", fit.correct[k]},
                    {"views_wrong", fit.wrong[k]},
                    {"distractors_matched", fit.distractor_matched[k]}});
  return {
      {"weight", fit.weight}, {"views", fit.queries}, {"views_listed", fit.listed}, {"distractors", fit.distractors},
      {"points", points},     {"model", model},       {"database", database},       {"ms_read", ms_read},
      {"ms_fit", ms_fit},     {"grid", grid}};
}

std::string MapBlendFit::summary(const std::string& map_dir) const {
  std::ostringstream s;
  s << map_dir << ": hash blend weight " << fit.weight << " (search with --hash-blend " << fit.weight << ")\n"
    << "  " << fit.queries << " held-out views of the " << points << " points (" << fit.listed
    << " with a short list), " << fit.distractors << " distractors; read in " << std::fixed << std::setprecision(0)
    << ms_read << " ms, fitted in " << ms_fit << " ms\n"
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
