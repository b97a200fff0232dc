// SegmentCache: segments of an opened map, memory-mapped on demand and kept
// in least-recently-used order under a byte budget (the mapped file sizes,
// the lookup tables and the coordinates decoded from quantized files).
// Thread-safe; a segment in use stays mapped (shared_ptr) even if evicted.
#pragma once

#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <unordered_map>

#include "visloc/map/map.h"

namespace visloc {

class SegmentCache {
 public:
  SegmentCache(const Map& map, uint64_t budget_bytes);
  // The segment at `index` in the manifest (opened on a miss).
  std::shared_ptr<const Segment> get(size_t index);
  uint64_t resident_bytes() const;
  size_t hits() const;
  size_t misses() const;

 private:
  const Map& map_;
  uint64_t budget_;
  mutable std::mutex mutex_;
  std::list<size_t> lru_;  // front = most recent
  struct Entry {
    std::shared_ptr<const Segment> segment;
    std::list<size_t>::iterator position;
    uint64_t bytes;
  };
  std::unordered_map<size_t, Entry> entries_;
  uint64_t resident_ = 0;
  size_t hits_ = 0, misses_ = 0;
};

}  // namespace visloc
