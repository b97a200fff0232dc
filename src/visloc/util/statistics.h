// Small statistics shared by the evaluation, the benchmarks and the readers.
#pragma once

#include <vector>

namespace visloc {

// Median of a sample (NaN when empty); even sizes average the middle two.
double median(std::vector<double> values);

}  // namespace visloc
