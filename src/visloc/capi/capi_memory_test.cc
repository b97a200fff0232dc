// Running out of memory is VISLOC_OUT_OF_MEMORY, whichever allocator fails:
// a child process with its address space capped (setrlimit) localizes a
// photo too large for the cap (SIFT's doubled first octave of a 6000×6000
// image needs ~1 GB), on the fountain-P11 map that the ctest fixture
// capi.import_fountain_map imports. A test executable of its own: the child
// is forked ("fast" death test, which also works under qemu-user) from a
// process whose OpenCV has never started its thread pool.
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <vector>

#include "visloc/capi/visloc.h"

namespace fs = std::filesystem;

namespace {

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif

// Bytes of address space this process has mapped (/proc/self/statm: pages).
long long mapped_bytes() {
  std::ifstream statm("/proc/self/statm");
  long long pages = 0;
  statm >> pages;
  return pages * 4096;
}

// Whether RLIMIT_AS takes effect: qemu-user ignores it for the guest (it needs
// the address space itself), so a capped child would allocate gigabytes.
bool address_space_cap_takes_effect() {
  rlimit old{};
  if (getrlimit(RLIMIT_AS, &old) != 0) return false;
  rlimit probe = old;
  probe.rlim_cur = static_cast<rlim_t>(1ll << 40);  // 1 TiB: harmless while it lasts
  if (old.rlim_max != RLIM_INFINITY && probe.rlim_cur > old.rlim_max) probe.rlim_cur = old.rlim_max;
  if (setrlimit(RLIMIT_AS, &probe) != 0) return false;
  rlimit seen{};
  const bool took = getrlimit(RLIMIT_AS, &seen) == 0 && seen.rlim_cur == probe.rlim_cur;
  setrlimit(RLIMIT_AS, &old);
  return took && probe.rlim_cur != old.rlim_cur;
}

[[noreturn]] void localize_within_a_cap(visloc_localizer* loc) {
  const int side = 6000;
  std::vector<uint8_t> pixels(static_cast<size_t>(side) * side);
  for (size_t i = 0; i < pixels.size(); ++i) pixels[i] = static_cast<uint8_t>((i * 2654435761u) >> 24);
  rlimit cap{};
  cap.rlim_cur = cap.rlim_max = static_cast<rlim_t>(mapped_bytes() + (256ll << 20));
  if (setrlimit(RLIMIT_AS, &cap) != 0) std::_Exit(100);
  visloc_result r;
  const visloc_status s = visloc_localize_gray(loc, pixels.data(), side, side, side, nullptr, &r);
  std::fprintf(stderr, "status %d: %s\n", static_cast<int>(s), r.error);
  std::_Exit(static_cast<int>(s));
}

}  // namespace

TEST(CapiMemory, ExhaustedMemoryIsOutOfMemory) {
  if (kAddressSanitizer) GTEST_SKIP() << "AddressSanitizer reserves terabytes of address space: no cap possible";
  if (!address_space_cap_takes_effect()) GTEST_SKIP() << "RLIMIT_AS does not take effect here (qemu-user ignores it)";
  const fs::path map = VISLOC_CAPI_TEST_MAP_DIR;
  if (!fs::exists(map / "manifest.json"))
    GTEST_SKIP() << "no map at " << map << " (the ctest fixture capi.import_fountain_map imports it; needs shared data)";
  visloc_options o;
  visloc_options_init(&o);
  o.max_image_side = 0;  // SIFT on the full 6000×6000 image
  o.threads = 1;         // no OpenCV thread pool to lose in the forked child
  visloc_localizer* loc = nullptr;
  char error[256];
  ASSERT_EQ(visloc_localizer_open(map.c_str(), &o, &loc, error, sizeof(error)), VISLOC_OK) << error;
  GTEST_FLAG_SET(death_test_style, "fast");
  EXPECT_EXIT(localize_within_a_cap(loc), ::testing::ExitedWithCode(VISLOC_OUT_OF_MEMORY), "status 6: ");
  visloc_localizer_close(loc);
}
