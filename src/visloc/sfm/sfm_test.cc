#include <gtest/gtest.h>
#include <pthread.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstring>

#include <filesystem>
#include <numeric>
#include <thread>

#include "visloc/colmap/colmap_database.h"
#include "visloc/sfm/colmap_database_writer.h"
#include "visloc/sfm/colmap_runner.h"
#include "visloc/sfm/process.h"
#include "visloc/sfm/segment_plan.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {
fs::path temp_dir(const std::string& name) { return unique_temp_dir("visloc_sfm_test_" + name); }
}  // namespace

TEST(PartitionSegments, WindowsOverlapAndRespectSizes) {
  SegmentPlanOptions o;  // 8-10 placemarks, overlap 2
  EXPECT_EQ(partition_segments(0, o).size(), 0u);
  ASSERT_EQ(partition_segments(7, o).size(), 1u);
  EXPECT_EQ(partition_segments(10, o)[0].size(), 10u);
  for (int n : {11, 18, 25, 26, 50, 101, 1000}) {
    auto segs = partition_segments(n, o);
    ASSERT_FALSE(segs.empty());
    EXPECT_EQ(segs.front().front(), 0) << n;
    EXPECT_EQ(segs.back().back(), n - 1) << n;
    for (size_t i = 0; i < segs.size(); ++i) {
      EXPECT_GE(static_cast<int>(segs[i].size()), o.min_placemarks) << "n=" << n << " seg " << i;
      EXPECT_LE(static_cast<int>(segs[i].size()), o.max_placemarks) << "n=" << n << " seg " << i;
      for (size_t j = 1; j < segs[i].size(); ++j) EXPECT_EQ(segs[i][j], segs[i][j - 1] + 1);
      if (i + 1 < segs.size()) {
        EXPECT_GE(segs[i].back() - segs[i + 1].front() + 1, o.overlap) << "n=" << n;
        if (n >= 2 * o.max_placemarks) {
          EXPECT_EQ(segs[i].back() - segs[i + 1].front() + 1, o.overlap) << "n=" << n;
        }
      }
    }
  }
}

TEST(PartitionSegments, ValidatesOptions) {
  SegmentPlanOptions o;
  o.overlap = 8;
  EXPECT_THROW(partition_segments(20, o), Error);
  o = {};
  o.max_placemarks = 5;
  EXPECT_THROW(o.validate(), Error);
}

TEST(GroupPlacemarks, ByColumnAndByRadius) {
  EnuFrame frame({46.5, 6.5, 400});
  auto rec = [&](const std::string& name, double e, double n, std::optional<int> pm) {
    GpsRecord r;
    r.image = name;
    r.position = frame.to_geo({e, n, 0});
    r.placemark = pm;
    return r;
  };
  std::vector<GpsRecord> with_ids = {rec("a", 0, 0, 5), rec("b", 0.5, 0, 5), rec("c", 10, 0, 6), rec("d", 10, 1, 6)};
  auto pms = group_placemarks(with_ids, frame, 3.0);
  ASSERT_EQ(pms.size(), 2u);
  EXPECT_EQ(pms[0].id, 5);
  EXPECT_EQ(pms[1].images, (std::vector<size_t>{2, 3}));
  EXPECT_NEAR(pms[1].center_enu.y(), 0.5, 1e-6);
  std::vector<GpsRecord> no_ids = {rec("a", 0, 0, {}), rec("b", 1, 0, {}), rec("c", 11, 0, {}), rec("d", 22, 0, {})};
  pms = group_placemarks(no_ids, frame, 3.0);
  ASSERT_EQ(pms.size(), 3u);
  EXPECT_EQ(pms[0].images.size(), 2u);
}

TEST(PlanSegments, ChainOrderRecoversRoute) {
  EnuFrame frame({46.5, 6.5, 400});
  // 30 placemarks along a bent street, listed in shuffled order.
  std::vector<int> order(30);
  std::iota(order.begin(), order.end(), 0);
  std::vector<int> shuffled = {17, 3, 29, 0, 11, 25, 8, 14, 21, 5, 1, 27, 19, 9, 2, 23, 13, 28, 6, 16, 10, 24, 4, 20, 12, 26, 7, 18, 22, 15};
  std::vector<GpsRecord> records;
  for (int k : shuffled) {
    GpsRecord r;
    r.image = "img" + std::to_string(k);
    Eigen::Vector3d p = k < 15 ? Eigen::Vector3d(11.0 * k, 0, 0) : Eigen::Vector3d(11.0 * 14, 11.0 * (k - 14), 0);
    r.position = frame.to_geo(p);
    records.push_back(r);
  }
  SegmentPlanOptions o;
  o.order = PlacemarkOrder::kChain;
  SegmentPlan plan = plan_segments(records, frame, o);
  ASSERT_EQ(plan.placemarks.size(), 30u);
  // Consecutive placemarks in the plan are neighbours on the street.
  for (size_t i = 1; i < plan.placemarks.size(); ++i)
    EXPECT_NEAR((plan.placemarks[i].center_enu - plan.placemarks[i - 1].center_enu).norm(), 11.0, 0.01);
  EXPECT_EQ(plan.segments.size(), 4u);
}

TEST(Process, MissingProgramAndFailureAreReported) {
  fs::path dir = temp_dir("process");
  try {
    run_process({"visloc-no-such-program-xyz", "--x"}, dir / "log.txt");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kNotFound);
    EXPECT_NE(std::string(e.what()).find("visloc-no-such-program-xyz"), std::string::npos);
  }
  auto ok = run_process({"sh", "-c", "echo hello-from-child"}, dir / "log.txt");
  EXPECT_EQ(ok.exit_code, 0);
  EXPECT_NE(read_file(dir / "log.txt").find("hello-from-child"), std::string::npos);
  try {
    run_process({"sh", "-c", "echo the-reason >&2; exit 3"}, dir / "log.txt");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kExternalTool);
    EXPECT_NE(std::string(e.what()).find("exit status 3"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("the-reason"), std::string::npos) << e.what();
  }
}

// A child process dies with the process that started it: `map build`
// killed with SIGKILL leaves no COLMAP writing on into its work folder.
TEST(Process, ChildDiesWithItsParent) {
  fs::path dir = temp_dir("process_orphan");
  const fs::path pid_file = dir / "child.pid";
  const pid_t builder = ::fork();
  ASSERT_GE(builder, 0);
  if (builder == 0) {  // stands for `map build`: starts a long child, then is killed
    try {
      run_process({"sh", "-c", "echo $$ > " + pid_file.string() + ".tmp && mv " + pid_file.string() + ".tmp " +
                                   pid_file.string() + " && exec sleep 60"},
                  dir / "log.txt");
    } catch (...) {
    }
    ::_exit(0);
  }
  for (int i = 0; i < 500 && !fs::exists(pid_file); ++i) ::usleep(10000);
  ASSERT_TRUE(fs::exists(pid_file)) << "the child never started";
  const pid_t child = std::stoi(read_file(pid_file));
  ::kill(builder, SIGKILL);
  ::waitpid(builder, nullptr, 0);
  // Dead means gone, or a zombie waiting for init to reap it.
  auto alive = [&] {
    const std::string stat_path = "/proc/" + std::to_string(child) + "/stat";
    if (!fs::exists(stat_path)) return false;
    std::string stat;
    try {
      stat = read_file(stat_path);
    } catch (const Error&) {
      return false;
    }
    const size_t paren = stat.rfind(')');
    return paren != std::string::npos && paren + 2 < stat.size() && stat[paren + 2] != 'Z';
  };
  bool still_alive = true;
  for (int i = 0; i < 300 && (still_alive = alive()); ++i) ::usleep(10000);
  EXPECT_FALSE(still_alive) << "child " << child << " outlived its killed parent";
  if (still_alive) ::kill(child, SIGKILL);
}

// An executable file the kernel cannot run: the error names the command
// and the reason, never a bare exit status.
TEST(Process, ExecFailureNamesTheReason) {
  fs::path dir = temp_dir("process_exec");
  const fs::path not_a_program = dir / "not-a-program";
  write_file_atomic(not_a_program, std::string("\x01\x02garbage", 9));
  fs::permissions(not_a_program, fs::perms::owner_all);
  try {
    run_process({not_a_program.string(), "--x"}, dir / "log.txt");
    FAIL() << "a file that is no program ran";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kExternalTool);
    EXPECT_NE(std::string(e.what()).find("cannot execute '" + not_a_program.string()), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(std::strerror(ENOEXEC)), std::string::npos) << e.what();
  }
}

// The child starts with the signal mask of the thread that started it (every
// signal is blocked while it is being set up, then restored).
TEST(Process, ChildHasTheCallersSignalMask) {
  fs::path dir = temp_dir("process_mask");
  auto child_mask = [&] {
    fs::remove(dir / "log.txt");
    run_process({"grep", "SigBlk", "/proc/self/status"}, dir / "log.txt");
    const std::string log = read_file(dir / "log.txt");
    const size_t at = log.find("SigBlk:");
    EXPECT_NE(at, std::string::npos) << log;
    if (at == std::string::npos) return std::string();
    std::string mask = log.substr(at + 7, log.find('\n', at) - at - 7);
    mask.erase(0, mask.find_first_not_of(" \t"));
    return mask;
  };
  struct MaskGuard {  // the test thread's mask back, whatever happens
    sigset_t old;
    MaskGuard() { ::pthread_sigmask(SIG_SETMASK, nullptr, &old); }
    ~MaskGuard() { ::pthread_sigmask(SIG_SETMASK, &old, nullptr); }
  } guard;
  sigset_t mask;
  ::sigemptyset(&mask);
  ASSERT_EQ(::pthread_sigmask(SIG_SETMASK, &mask, nullptr), 0);
  EXPECT_EQ(child_mask(), "0000000000000000");
  ::sigaddset(&mask, SIGUSR2);  // signal 12: bit 11
  ASSERT_EQ(::pthread_sigmask(SIG_SETMASK, &mask, nullptr), 0);
  EXPECT_EQ(child_mask(), "0000000000000800");
}

// Starting a child runs no pthread_atfork handler: libraries' fork handlers
// (OpenBLAS stops its thread pool in one) run while other threads work, and
// a fork copies the locks those threads hold.
namespace {
std::atomic<int> g_fork_prepare_calls{0};
}  // namespace
TEST(Process, StartingAChildRunsNoForkHandler) {
  static const bool registered = ::pthread_atfork([] { ++g_fork_prepare_calls; }, nullptr, nullptr) == 0;
  ASSERT_TRUE(registered);
  fs::path dir = temp_dir("process_atfork");
  const int before = g_fork_prepare_calls.load();
  run_process({"true"}, dir / "log.txt");
  EXPECT_EQ(g_fork_prepare_calls, before);
  const pid_t forked = ::fork();  // the handler is live: fork runs it
  if (forked == 0) ::_exit(0);
  ASSERT_GT(forked, 0);
  ::waitpid(forked, nullptr, 0);
  EXPECT_EQ(g_fork_prepare_calls, before + 1);
}

// Building threads start their COLMAP runs at the same time while others
// allocate and write files: every run starts, ends with its own exit status
// and writes its own log.
TEST(Process, ManyThreadsStartChildrenAtOnce) {
  fs::path dir = temp_dir("process_threads");
  constexpr int kThreads = 4, kRuns = 25;
  std::atomic<bool> stop{false};
  std::thread busy([&] {
    std::vector<std::string> keep(32);
    for (unsigned i = 0; !stop; ++i) {
      keep[i % keep.size()].assign(1 + (i * 2654435761u) % 200000, 'x');
      write_file_atomic(dir / ("busy" + std::to_string(i % 2) + ".txt"), keep[i % keep.size()].substr(0, 64));
    }
  });
  std::vector<int> ok(kThreads, 0);
  std::vector<std::thread> starters;
  for (int t = 0; t < kThreads; ++t)
    starters.emplace_back([&, t] {
      for (int r = 0; r < kRuns; ++r) {
        const fs::path log = dir / ("log" + std::to_string(t) + ".txt");
        const std::string token = "run-" + std::to_string(t) + "-" + std::to_string(r);
        try {
          run_process({"sh", "-c", "echo " + token + "; exit " + std::to_string(r % 2 ? 0 : 5)}, log);
          // The child's own line (the header run_process writes quotes the command).
          ok[t] += r % 2 == 1 && read_file(log).find("\n" + token + "\n") != std::string::npos;
        } catch (const Error& e) {
          ok[t] += r % 2 == 0 && std::string(e.what()).find("exit status 5") != std::string::npos &&
                   std::string(e.what()).find("    " + token + "\n") != std::string::npos;  // the log's tail
        }
      }
    });
  for (auto& s : starters) s.join();
  stop = true;
  busy.join();
  for (int t = 0; t < kThreads; ++t) EXPECT_EQ(ok[t], kRuns) << "thread " << t;
}

TEST(ColmapDatabaseWriter, RoundTripThroughReader) {
  fs::path dir = temp_dir("dbwriter");
  FeatureSet f;
  f.keypoints = {{10.5f, 20.5f, 2.0f, 0.5f}, {100.f, 50.f, 3.f, -1.f}};
  f.descriptors = DescriptorMatrix(2);
  for (size_t i = 0; i < f.descriptors.size_bytes(); ++i) f.descriptors.data()[i] = static_cast<uint8_t>(i % 251);
  {
    ColmapDatabaseWriter w(dir / "database.db");
    PinholeCamera cam = PinholeCamera::centered(640, 480, 500.0);
    int64_t cid = w.add_camera(cam);
    int64_t iid = w.add_image("a.jpg", cid, Eigen::Vector3d(1, 2, 3));
    w.add_features(iid, f);
    w.add_image("b.jpg", cid);
    w.commit();
  }
  ColmapDatabase db(dir / "database.db");
  auto images = db.images();
  ASSERT_EQ(images.size(), 2u);
  EXPECT_EQ(images[0].name, "a.jpg");
  auto cams = db.cameras();
  ASSERT_EQ(cams.size(), 1u);
  EXPECT_EQ(cams[0].model, kColmapSimplePinhole);
  EXPECT_DOUBLE_EQ(cams[0].params[0], 500.0);
  FeatureSet g = db.features(images[0].image_id);
  ASSERT_EQ(g.size(), 2u);
  EXPECT_FLOAT_EQ(g.keypoints[1].x, 100.f);
  EXPECT_FLOAT_EQ(g.keypoints[1].orientation, -1.f);
  EXPECT_EQ(0, std::memcmp(g.descriptors.data(), f.descriptors.data(), f.descriptors.size_bytes()));
}

TEST(ColmapDatabaseWriter, AppendsAndRemovesImages) {
  fs::path dir = temp_dir("dbappend");
  FeatureSet f;
  f.keypoints = {{10.5f, 20.5f, 2.0f, 0.5f}};
  f.descriptors = DescriptorMatrix(1);
  EXPECT_THROW(ColmapDatabaseWriter(dir / "absent.db", ColmapDatabaseWriter::Mode::kAppend), Error);
  {
    ColmapDatabaseWriter w(dir / "database.db");
    const int64_t cid = w.add_camera(PinholeCamera::centered(640, 480, 500.0));
    w.add_features(w.add_image("a.jpg", cid), f);
    w.add_features(w.add_image("b.jpg", cid), f);
    w.commit();
  }
  {
    ColmapDatabaseWriter w(dir / "database.db", ColmapDatabaseWriter::Mode::kAppend);
    EXPECT_TRUE(w.remove_image("a.jpg"));
    EXPECT_FALSE(w.remove_image("zzz.jpg"));
    const int64_t cid = w.add_camera(PinholeCamera::centered(320, 240, 300.0));
    w.add_features(w.add_image("c.jpg", cid), f);
    w.commit();
  }
  ColmapDatabase db(dir / "database.db");
  auto images = db.images();
  ASSERT_EQ(images.size(), 2u);
  EXPECT_EQ(images[0].name, "b.jpg");
  EXPECT_EQ(images[1].name, "c.jpg");
  EXPECT_FALSE(db.image_by_name("a.jpg").has_value());
  EXPECT_EQ(db.features(images[1].image_id).size(), 1u);
  EXPECT_EQ(db.cameras().size(), 2u);
}

TEST(ColmapDatabaseWriter, UncommittedWriteLeavesNoImages) {
  fs::path dir = temp_dir("dbrollback");
  {
    ColmapDatabaseWriter w(dir / "database.db");
    w.add_camera(PinholeCamera::centered(64, 48, 50.0));
  }
  ColmapDatabase db(dir / "database.db");
  EXPECT_TRUE(db.cameras().empty());
}

TEST(ColmapTextModel, WritesPosesColmapCanRead) {
  fs::path dir = temp_dir("textmodel");
  CameraPose pose = CameraPose::from_wxyz({0.9, 0.1, 0.2, 0.3}, {1, 2, 3});
  write_colmap_text_model(dir, {{1, PinholeCamera::centered(640, 480, 500.0)}}, {{1, 1, "a.jpg", pose}});
  std::string images = read_file(dir / "images.txt");
  EXPECT_NE(images.find(" 1 a.jpg\n\n"), std::string::npos) << images;
  EXPECT_NE(read_file(dir / "cameras.txt").find("1 SIMPLE_PINHOLE 640 480 500 320 240"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir / "points3D.txt"));
}

TEST(ColmapRunner, StrategyChoiceAndOptions) {
  EXPECT_EQ(choose_match_strategy(30, false), ColmapMatchStrategy::kExhaustive);
  EXPECT_EQ(choose_match_strategy(300, true), ColmapMatchStrategy::kSpatial);
  EXPECT_EQ(choose_match_strategy(300, false), ColmapMatchStrategy::kSequential);
  ColmapRunnerOptions o;
  o.threads = 0;
  EXPECT_THROW(ColmapRunner{o}, Error);
}

TEST(ColmapDatabaseWriter, CalibratedPairsAreStoredUnderColmapsPairId) {
  fs::path dir = temp_dir("dbpairs");
  int64_t a = 0, b = 0;
  {
    ColmapDatabaseWriter w(dir / "database.db");
    const int64_t cid = w.add_camera(PinholeCamera::centered(640, 480, 500.0));
    a = w.add_image("a.jpg", cid);
    b = w.add_image("b.jpg", cid);
    const Eigen::Matrix3d F = Eigen::Matrix3d::Identity(), E = Eigen::Matrix3d::Identity();
    // Given as (b, a): stored as (a, b) with the columns swapped.
    w.add_calibrated_pair(b, a, {{7, 1}, {9, 2}}, F, E, Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 0, 0));
    EXPECT_THROW(w.add_calibrated_pair(a, a, {}, F, E, Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 0, 0)),
                 Error);
    w.commit();
  }
  ColmapDatabase db(dir / "database.db");
  const auto m = db.verified_matches(a, b);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0], std::make_pair(uint32_t{1}, uint32_t{7}));
  EXPECT_EQ(m[1], std::make_pair(uint32_t{2}, uint32_t{9}));
}

TEST(ColmapDatabaseWriter, VerifiedPairsKeepRawMatchesAndInliersApart) {
  fs::path dir = temp_dir("dbverified");
  int64_t a = 0, b = 0, c = 0;
  {
    ColmapDatabaseWriter w(dir / "database.db");
    const int64_t cid = w.add_camera(PinholeCamera::centered(640, 480, 500.0));
    a = w.add_image("a.jpg", cid);
    b = w.add_image("b.jpg", cid);
    c = w.add_image("c.jpg", cid);
    Eigen::Matrix3d F;
    F << 0, -1, 2, 1, 0, -3, -2, 3, 0;
    // (b, a): stored as (a, b), columns swapped; uncalibrated (F only).
    w.add_verified_pair(b, a, {{7, 1}, {9, 2}, {4, 4}}, {{7, 1}, {9, 2}}, F, std::nullopt);
    w.add_verified_pair(a, c, {{1, 5}, {3, 6}}, {{3, 6}}, F, Eigen::Matrix3d::Identity());  // calibrated
    w.commit();
  }
  ColmapDatabase db(dir / "database.db");
  const auto m = db.verified_matches(a, b);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0], std::make_pair(uint32_t{1}, uint32_t{7}));
  EXPECT_EQ(m[1], std::make_pair(uint32_t{2}, uint32_t{9}));
  ASSERT_EQ(db.verified_matches(a, c).size(), 1u);
  // The raw matches, the configurations and F as COLMAP reads them.
  sqlite3* raw = nullptr;
  ASSERT_EQ(sqlite3_open_v2((dir / "database.db").c_str(), &raw, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  auto query = [&](const std::string& sql, auto&& row) {
    sqlite3_stmt* s = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(raw, sql.c_str(), -1, &s, nullptr), SQLITE_OK) << sql;
    while (sqlite3_step(s) == SQLITE_ROW) row(s);
    sqlite3_finalize(s);
  };
  std::vector<std::pair<int64_t, int64_t>> match_rows, configs;
  query("SELECT rows FROM matches ORDER BY pair_id",
        [&](sqlite3_stmt* s) { match_rows.emplace_back(sqlite3_column_int64(s, 0), 0); });
  query("SELECT config, F FROM two_view_geometries ORDER BY pair_id", [&](sqlite3_stmt* s) {
    configs.emplace_back(sqlite3_column_int64(s, 0), 0);
    const double* f = static_cast<const double*>(sqlite3_column_blob(s, 1));
    ASSERT_EQ(sqlite3_column_bytes(s, 1), 72);
    EXPECT_EQ(f[1], configs.size() == 1 ? 1.0 : -1.0) << "F transposed for the swapped pair";
  });
  sqlite3_close(raw);
  ASSERT_EQ(match_rows.size(), 2u);
  EXPECT_EQ(match_rows[0].first, 3);  // (a, b): every raw match
  EXPECT_EQ(match_rows[1].first, 2);
  ASSERT_EQ(configs.size(), 2u);
  EXPECT_EQ(configs[0].first, kColmapUncalibratedPair);
  EXPECT_EQ(configs[1].first, kColmapCalibratedPair);
}

#include "visloc/sfm/slurm.h"

TEST(Slurm, ShellQuotingSurvivesTheShell) {
  const std::string tricky = "it's a \"map\" $HOME `x` \\ dir";
  const fs::path dir = temp_dir("quote");
  run_process({"/bin/sh", "-c", "printf %s " + shell_quote(tricky)}, dir / "out.txt");
  const std::string out = read_file(dir / "out.txt");
  EXPECT_EQ(out.substr(out.size() - tricky.size()), tricky);
}

TEST(Slurm, OptionsAreValidated) {
  SlurmOptions o;
  o.poll_seconds = 0;
  EXPECT_THROW(o.validate(), Error);
  o = {};
  o.cpus_per_task = 0;
  EXPECT_THROW(o.validate(), Error);
  o = {};
  EXPECT_THROW(SlurmArray::submit(o, {}, {"true"}, temp_dir("slurm_empty")), Error);
}
