// Fuzzes GPS CSV files (geo/gps_csv.h read_gps_csv), then puts every record
// in a local ENU frame around the first, as the map builder does.
#include "fuzz_harness.h"
#include "visloc/geo/enu_frame.h"
#include "visloc/geo/gps_csv.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("gps.csv", data, size);
  fuzz::accepts([&] {
    const std::vector<GpsRecord> records = read_gps_csv(path);
    if (records.empty()) return;
    const EnuFrame frame(records.front().position);
    double sum = 0;
    for (const GpsRecord& r : records) sum += frame.to_enu(r.position).norm() + r.placemark.value_or(0);
    if (sum == 0.125) std::fputc('.', stderr);
  });
  return 0;
}
