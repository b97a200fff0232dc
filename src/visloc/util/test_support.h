// Helpers shared by the tests (header-only; not part of the library's API):
// temporary paths unique to the test process, and error capture.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <functional>
#include <mutex>
#include <string>
#include <system_error>
#include <vector>

#include "visloc/util/error.h"

namespace visloc {

// A path under the system's temporary folder, unique to this process (ctest
// runs every test as a process of its own, and two builds may run their
// suites at once), removed with everything under it when the process exits.
// Nothing is created.
inline std::filesystem::path unique_temp_path(const std::string& name) {
  struct Registry {
    std::mutex mutex;
    std::vector<std::filesystem::path> paths;
    ~Registry() {
      for (const auto& p : paths) {
        std::error_code ec;
        std::filesystem::remove_all(p, ec);
      }
    }
  };
  static Registry registry;
  const std::filesystem::path p =
      std::filesystem::temp_directory_path() / (std::to_string(::getpid()) + "_" + name);  // keeps an extension
  std::lock_guard<std::mutex> lock(registry.mutex);
  registry.paths.push_back(p);
  return p;
}

// unique_temp_path(name) as an empty folder (emptied if a previous run of
// the same process id left it).
inline std::filesystem::path unique_temp_dir(const std::string& name) {
  const std::filesystem::path p = unique_temp_path(name);
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p;
}

// The message of the visloc::Error that f throws; "" when it throws none.
inline std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace visloc
