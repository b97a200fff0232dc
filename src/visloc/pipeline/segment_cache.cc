#include "visloc/pipeline/segment_cache.h"

namespace visloc {

SegmentCache::SegmentCache(const Map& map, uint64_t budget_bytes) : map_(map), budget_(budget_bytes) {}

std::shared_ptr<const Segment> SegmentCache::get(size_t index) {
  {
    std::lock_guard lock(mutex_);
    auto it = entries_.find(index);
    if (it != entries_.end()) {
      lru_.splice(lru_.begin(), lru_, it->second.position);
      ++hits_;
      return it->second.segment;
    }
    ++misses_;
  }
  // Open outside the lock (mapping + checksum verification take time).
  std::shared_ptr<const Segment> seg = map_.open_segment(index);
  // The mapped file, the lookup tables built at load and decoded coordinates (quantized files).
  const uint64_t bytes = seg->bytes().file + seg->bytes().lookup_memory + seg->bytes().xyz_memory;
  std::lock_guard lock(mutex_);
  auto it = entries_.find(index);
  if (it != entries_.end()) return it->second.segment;  // another thread was quicker
  lru_.push_front(index);
  entries_[index] = {seg, lru_.begin(), bytes};
  resident_ += bytes;
  while (resident_ > budget_ && lru_.size() > 1) {
    const size_t victim = lru_.back();
    lru_.pop_back();
    resident_ -= entries_[victim].bytes;
    entries_.erase(victim);
  }
  return seg;
}

uint64_t SegmentCache::resident_bytes() const {
  std::lock_guard lock(mutex_);
  return resident_;
}
size_t SegmentCache::hits() const {
  std::lock_guard lock(mutex_);
  return hits_;
}
size_t SegmentCache::misses() const {
  std::lock_guard lock(mutex_);
  return misses_;
}

}  // namespace visloc
