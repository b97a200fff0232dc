#include "visloc/map_building/segment_builder.h"

#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

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
