#include "visloc/pipeline/localization_json.h"

namespace visloc {

nlohmann::json to_json(const LocalizationResult& r) {
  nlohmann::json j;
  j["image"] = r.image;
  j["registered"] = r.registered;
  if (!r.error.empty()) j["error"] = r.error;
  j["segment"] = r.segment;
  j["inliers"] = r.inliers;
  j["confidence"] = r.confidence;
  if (r.segment >= 0) {
    j["confidence_features"] = r.confidence_features.to_json();
    if (r.uncertainty.valid) {
      const PoseUncertainty& u = r.uncertainty;
      nlohmann::json a = {{"position_sigma", u.position_sigma}, {"rotation_sigma_deg", u.rotation_sigma_deg}};
      if (u.position_sigma_m) a["position_sigma_m"] = *u.position_sigma_m;
      if (u.horizontal_sigma_m) a["horizontal_sigma_m"] = *u.horizontal_sigma_m;
      if (u.vertical_sigma_m) a["vertical_sigma_m"] = *u.vertical_sigma_m;
      if (u.heading_sigma_deg) a["heading_sigma_deg"] = *u.heading_sigma_deg;
      if (u.relative_position_sigma > 0) a["relative_position_sigma"] = u.relative_position_sigma;
      a["sigma_scale"] = u.sigma_scale;
      a["map_point_uncertainty"] = u.map_point_uncertainty;
      j["uncertainty"] = a;
    }
    if (r.under_street.assessed) {
      const UnderStreetAssessment& u = r.under_street;
      nlohmann::json a = {{"under_street", u.under_street},
                          {"drop_below_map_camera_m", u.drop_below_camera_m},
                          {"map_camera_plan_distance_m", u.camera_plan_distance_m}};
      if (u.above_ground_m) a["above_map_ground_m"] = *u.above_ground_m;
      j["plausibility"] = a;
    }
    const auto q = r.cam_from_segment.q_wxyz();
    j["q_wxyz"] = {q[0], q[1], q[2], q[3]};
    const auto& t = r.cam_from_segment.translation;
    j["t"] = {t.x(), t.y(), t.z()};
    j["focal_px"] = r.focal_px;
    j["focal_estimated"] = r.focal_estimated;
    if (r.focal_estimated)
      j["principal_point_offset_px"] = {r.principal_point_offset.x(), r.principal_point_offset.y()};
  }
  if (r.center_enu) j["center_enu"] = {r.center_enu->x(), r.center_enu->y(), r.center_enu->z()};
  if (r.position) {
    j["lat"] = r.position->lat;
    j["lon"] = r.position->lon;
    j["alt"] = r.position->alt;
  }
  if (r.heading_deg) j["heading_deg"] = *r.heading_deg;
  j["candidates"] = r.candidates;
  if (!r.retrieval_segments.empty())
    j["retrieval"] = {{"segments", r.retrieval_segments},
                      {"votes", r.retrieval_votes},
                      {"voted_segments", r.retrieval_voted_segments},
                      {"total_votes", r.retrieval_total_votes}};
  if (r.full_search_fallback) j["full_search_fallback"] = true;
  if (r.fallback_segments_searched) j["fallback_segments_searched"] = true;
  j["features"] = r.features;
  j["times_ms"] = {{"features", r.times.features},
                   {"retrieval", r.times.retrieval},
                   {"matching", r.times.matching},
                   {"ransac", r.times.ransac},
                   {"total", r.times.total}};
  return j;
}

}  // namespace visloc
