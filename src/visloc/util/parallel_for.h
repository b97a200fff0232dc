// parallel_for: fn(i) for every i in [0, n) on up to `jobs` threads (the
// calling thread is one of them), items handed out one at a time in order.
// The first exception stops the hand-out of new items and is rethrown once
// every thread has ended; items already started run to completion.
#pragma once

#include <cstddef>
#include <functional>

namespace visloc {

void parallel_for(size_t n, int jobs, const std::function<void(size_t)>& fn);

}  // namespace visloc
