#include "visloc/map_building/segment_builder.h"

#include <cmath>

#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

void point_uncertainty_of_model(const ColmapModel& model, std::vector<PointUncertaintyCode>* codes,
                                double* keypoint_noise_px) {
  codes->clear();
  *keypoint_noise_px = 0;
  std::vector<double> errors;
  std::vector<uint32_t> lengths;
  errors.reserve(model.points.size());
  lengths.reserve(model.points.size());
  for (const auto& p : model.points) {
    errors.push_back(p.error);
    lengths.push_back(static_cast<uint32_t>(p.track.size()));
  }
  const double noise = keypoint_noise_from_reprojection_errors(errors, lengths);
  if (!(noise > 0)) return;  // exact points (a planted map) or no errors: nothing to store
  std::vector<TrackCamera> cameras(model.images.size());
  for (size_t i = 0; i < model.images.size(); ++i) {
    const ColmapImage& im = model.images[i];
    const ColmapCamera& cam = model.cameras[static_cast<size_t>(model.camera_index(im.camera_id))];
    const CameraPose pose = colmap_image_pose(im);
    cameras[i].R = pose.rotation_matrix();
    cameras[i].t = pose.translation;
    // fx, and fy but for the one-focal models (SIMPLE_PINHOLE 0, SIMPLE_RADIAL
    // 2, RADIAL 3, SIMPLE_RADIAL_FISHEYE 8, RADIAL_FISHEYE 9).
    const int m = cam.model_id;
    const bool two_focals = !(m == 0 || m == 2 || m == 3 || m == 8 || m == 9);
    cameras[i].fx = cam.params.at(0);
    cameras[i].fy = two_focals ? cam.params.at(1) : cam.params.at(0);
  }
  codes->resize(model.points.size());
  std::vector<TrackCamera> track;
  for (size_t p = 0; p < model.points.size(); ++p) {
    const ColmapPoint3D& point = model.points[p];
    track.clear();
    for (const auto& e : point.track) {
      const int64_t i = model.image_index(e.image_id);
      if (i >= 0) track.push_back(cameras[static_cast<size_t>(i)]);
    }
    const Eigen::Vector3d X(point.xyz[0], point.xyz[1], point.xyz[2]);
    (*codes)[p] = encode_point_covariance(triangulation_covariance(X, track, noise));
  }
  *keypoint_noise_px = noise;
}

SegmentData make_segment_data(const ColmapModel& model, const PointDescriptors& desc, const PqCodebook& codebook,
                              const ItqOptions& itq_options, uint32_t segment_id, SegmentBuildStats* stats,
                              const BinaryHasher* map_hasher) {
  VISLOC_CHECK(desc.num_points == model.points.size(), "descriptors and points differ in count");
  Timer t;
  ItqResult itq;
  if (!map_hasher) {
    itq = train_itq(desc.mean.data(), desc.num_points, itq_options);
    if (stats) {
      stats->itq_final_error = itq.quantization_error.empty() ? 0 : itq.quantization_error.back();
      stats->ms_itq = t.elapsed_ms();
    }
  }
  t.reset();
  SegmentData seg;
  seg.segment_id = segment_id;
  seg.xyz.resize(3 * desc.num_points);
  for (size_t p = 0; p < model.points.size(); ++p)
    for (int k = 0; k < 3; ++k) seg.xyz[3 * p + k] = static_cast<float>(model.points[p].xyz[k]);
  seg.codes.resize(desc.num_points);
  HashWorkspace workspace;
  if (map_hasher) {
    encode_hash(map_hasher->view(), desc.mean.data(), desc.num_points, seg.codes.data(), workspace);
    seg.extra_meta["hash_rotation_crc32c"] = hash_rotation_fingerprint(*map_hasher);
  } else {
    seg.hasher = std::move(itq.hasher);
    encode_hash(seg.hasher.view(), desc.mean.data(), desc.num_points, seg.codes.data(), workspace);
  }
  seg.pq_subvectors = codebook.subvectors();
  seg.pq_codes.resize(desc.num_points * size_t(codebook.code_bytes()));
  codebook.encode(desc.mean.data(), desc.num_points, seg.pq_codes.data());
  for (const auto& im : model.images) {
    const auto& cam = model.cameras[model.camera_index(im.camera_id)];
    seg.images.push_back({im.name, cam.model_id, cam.width, cam.height, cam.params, im.cam_from_world_q_wxyz,
                          im.cam_from_world_t});
  }
  if (stats) stats->ms_encode = t.elapsed_ms();
  return seg;
}

}  // namespace visloc
