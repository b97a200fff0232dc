#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <stdexcept>
#include <vector>

#include "visloc/util/base64.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/mapped_file.h"
#include "visloc/util/option_table.h"
#include "visloc/util/parallel_for.h"
#include "visloc/util/section_file.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path temp_dir() {
  fs::path dir = unique_temp_path(std::string("visloc_util_test_") +
                                  ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void write_sample(const fs::path& path) {
  SectionFileWriter w(path, "TEST", 3);
  std::vector<float> values(100);
  std::iota(values.begin(), values.end(), 0.5f);
  w.add_array<float>("VALUES", values);
  w.add_text("META", "{\"hello\": 1}");
  w.add("EMPTY", nullptr, 0);
  w.commit();
}

}  // namespace

TEST(Crc32c, KnownVectors) {
  EXPECT_EQ(crc32c("123456789", 9), 0xE3069283u);
  EXPECT_EQ(crc32c("", 0), 0u);
  std::vector<uint8_t> zeros(32, 0);
  EXPECT_EQ(crc32c(zeros.data(), zeros.size()), 0x8A9136AAu);  // RFC 3720 B.4
}

TEST(Crc32c, IncrementalEqualsWhole) {
  std::string s = "The quick brown fox jumps over the lazy dog, twice over.";
  uint32_t whole = crc32c(s.data(), s.size());
  uint32_t part = crc32c(s.data(), 13);
  part = crc32c(s.data() + 13, s.size() - 13, part);
  EXPECT_EQ(whole, part);
}

TEST(AtomicFileWriter, NothingLeftWithoutCommit) {
  fs::path dir = temp_dir();
  {
    AtomicFileWriter w(dir / "a.bin");
    w.write("partial");
  }
  EXPECT_FALSE(fs::exists(dir / "a.bin"));
  EXPECT_TRUE(fs::is_empty(dir));
}

TEST(AtomicFileWriter, CommitReplacesTarget) {
  fs::path dir = temp_dir();
  write_file_atomic(dir / "a.txt", "old");
  write_file_atomic(dir / "a.txt", "new content");
  EXPECT_EQ(read_file(dir / "a.txt"), "new content");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
}

TEST(AtomicFileWriter, UnwritableDirectoryNamesFile) {
  std::string msg = error_of([] { AtomicFileWriter w("/nonexistent_dir_xyz/file.bin"); });
  EXPECT_NE(msg.find("/nonexistent_dir_xyz/file.bin"), std::string::npos) << msg;
}

TEST(MappedFile, MissingFileNamesIt) {
  std::string msg = error_of([] { MappedFile f("/nonexistent_file_xyz.bin"); });
  EXPECT_NE(msg.find("nonexistent_file_xyz.bin"), std::string::npos) << msg;
}

TEST(SectionFile, RoundTrip) {
  fs::path p = temp_dir() / "sample.vl";
  write_sample(p);
  SectionFileReader r(p, "TEST", 1, 3);
  EXPECT_EQ(r.kind_version(), 3u);
  auto values = r.array<float>("VALUES", 100);
  ASSERT_EQ(values.size(), 100u);
  EXPECT_FLOAT_EQ(values[0], 0.5f);
  EXPECT_FLOAT_EQ(values[99], 99.5f);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(values.data()) % kSectionAlignment, 0u);
  EXPECT_EQ(r.text("META"), "{\"hello\": 1}");
  EXPECT_EQ(r.bytes("EMPTY").size(), 0u);
  EXPECT_FALSE(r.has("NOPE"));
  EXPECT_THROW(r.bytes("NOPE"), Error);
  EXPECT_THROW(r.array<float>("VALUES", 99), Error);
  EXPECT_THROW(r.array<double>("META"), Error);
}

TEST(SectionFile, RejectsWrongKindAndVersion) {
  fs::path p = temp_dir() / "sample.vl";
  write_sample(p);
  EXPECT_NE(error_of([&] { SectionFileReader r(p, "SEGM", 1, 3); }).find("expected 'SEGM'"),
            std::string::npos);
  std::string msg = error_of([&] { SectionFileReader r(p, "TEST", 4, 5); });
  EXPECT_NE(msg.find("format version 3"), std::string::npos) << msg;
  EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
}

TEST(SectionFile, RejectsEveryTruncation) {
  fs::path dir = temp_dir();
  fs::path p = dir / "sample.vl";
  write_sample(p);
  std::string content = read_file(p);
  for (size_t len : {size_t{0}, size_t{10}, size_t{63}, size_t{64}, content.size() / 2,
                     content.size() - 1}) {
    fs::path t = dir / ("trunc_" + std::to_string(len));
    write_file_atomic(t, std::string_view(content).substr(0, len));
    std::string msg = error_of([&] { SectionFileReader r(t, "TEST", 1, 3); });
    EXPECT_FALSE(msg.empty()) << "truncation to " << len << " bytes was accepted";
    EXPECT_NE(msg.find(t.string()), std::string::npos) << msg;
  }
}

TEST(SectionFile, RejectsAnySingleBitFlip) {
  fs::path dir = temp_dir();
  fs::path p = dir / "sample.vl";
  write_sample(p);
  const std::string content = read_file(p);
  SectionFileReader ok(p, "TEST", 1, 3);
  // Flip one bit in every byte that carries meaning (padding bytes are free).
  int rejected = 0, meaningful = 0;
  std::vector<bool> padding(content.size(), true);
  for (size_t i = 0; i < sizeof(SectionFileHeader); ++i) padding[i] = false;
  for (const auto& e : ok.sections())
    for (size_t i = 0; i < e.size; ++i) padding[e.offset + i] = false;
  for (size_t i = content.size() - ok.sections().size() * sizeof(SectionEntry); i < content.size(); ++i)
    padding[i] = false;
  for (size_t i = 0; i < content.size(); ++i) {
    if (padding[i]) continue;
    ++meaningful;
    std::string bad = content;
    bad[i] = static_cast<char>(bad[i] ^ (1 << (i % 8)));
    fs::path t = dir / "flipped.vl";
    write_file_atomic(t, bad);
    if (!error_of([&] { SectionFileReader r(t, "TEST", 1, 3); }).empty()) ++rejected;
  }
  EXPECT_EQ(rejected, meaningful);
}

TEST(Base64, KnownVectorsRoundTripAndRejects) {
  // RFC 4648, section 10.
  const std::pair<const char*, const char*> vectors[] = {{"", ""},         {"f", "Zg=="},         {"fo", "Zm8="},
                                                          {"foo", "Zm9v"}, {"foob", "Zm9vYg=="},   {"fooba", "Zm9vYmE="},
                                                          {"foobar", "Zm9vYmFy"}};
  for (const auto& [plain, encoded] : vectors) {
    EXPECT_EQ(visloc::base64_encode(plain, std::strlen(plain)), encoded);
    const auto back = visloc::base64_decode(encoded);
    ASSERT_TRUE(back.has_value());
    EXPECT_EQ(std::string(back->begin(), back->end()), plain);
  }
  std::vector<uint8_t> all(256 * 3 + 1);
  for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<uint8_t>(i * 7 + 3);
  EXPECT_EQ(*visloc::base64_decode(visloc::base64_encode(all.data(), all.size())), all);
  for (const char* bad : {"Zg=", "Z===", "Zg==Zg==", "Zm9v!A==", "=Zm9"}) EXPECT_FALSE(visloc::base64_decode(bad)) << bad;
}

TEST(ParallelFor, VisitsEveryIndexOnce) {
  for (int jobs : {0, 1, 2, 8})
    for (size_t n : {size_t{0}, size_t{1}, size_t{3}, size_t{200}}) {
      std::vector<std::atomic<int>> visits(n);
      visloc::parallel_for(n, jobs, [&](size_t i) { visits[i]++; });
      for (size_t i = 0; i < n; ++i) EXPECT_EQ(visits[i].load(), 1) << "jobs " << jobs << ", n " << n << ", i " << i;
    }
}

TEST(ParallelFor, FirstExceptionStopsTheHandOutAndIsRethrown) {
  std::atomic<int> started{0};
  EXPECT_THROW(visloc::parallel_for(100, 1, [&](size_t i) {
                 started++;
                 if (i == 10) throw std::runtime_error("item 10");
               }),
               std::runtime_error);
  EXPECT_EQ(started.load(), 11);  // one thread: nothing after the failing item starts
  try {
    visloc::parallel_for(50, 4, [&](size_t i) {
      if (i % 7 == 3) throw visloc::Error(visloc::ErrorCode::kIo, "item failed");
    });
    FAIL() << "no exception";
  } catch (const visloc::Error& e) {
    EXPECT_EQ(e.code(), visloc::ErrorCode::kIo);
  }
}

namespace {
enum class Colour { kRed, kGreen };
}

TEST(OptionTable, EntriesCarryNamesFieldsDefaultsAndChoices) {
  int count = 7;
  double ratio = 0.25;
  bool fallback = true;
  Colour colour = Colour::kGreen;
  std::vector<double> list;
  OptionTable t;
  t.add("--count", count, "how many").non_negative();
  t.add("--ratio", ratio, "a ratio").range(0, 1);
  t.flag("!--no-fallback", fallback, "no fallback");
  t.choice("--colour", colour, {{"red", Colour::kRed}, {"green", Colour::kGreen}}, "a colour");
  t.text("--list", "1,2", [&list](const std::string& v) { list = parse_number_list(v, "--list"); }, "numbers");
  ASSERT_EQ(t.entries().size(), 5u);
  const auto& e = t.entries();
  EXPECT_EQ(e[0].default_text, "7");
  EXPECT_TRUE(std::holds_alternative<int*>(e[0].field));
  EXPECT_EQ(std::get<int*>(e[0].field), &count);
  EXPECT_EQ(e[0].min, 0.0);
  EXPECT_EQ(e[1].default_text, "0.25");
  EXPECT_EQ(e[1].max, 1.0);
  EXPECT_TRUE(e[2].flag);
  EXPECT_FALSE(e[2].show_default);
  EXPECT_EQ(e[3].default_text, "green");
  EXPECT_EQ(e[3].choices, (std::vector<std::string>{"red", "green"}));
  e[3].parse("red");
  EXPECT_EQ(colour, Colour::kRed);
  EXPECT_THROW(e[3].parse("blue"), Error);
  e[4].parse("3,4.5");
  EXPECT_EQ(list, (std::vector<double>{3, 4.5}));
  // Negated flags are found by either spelling; a second declaration is a bug.
  EXPECT_EQ(t.find("--no-fallback"), &e[2]);
  EXPECT_EQ(t.find("!--no-fallback"), &e[2]);
  EXPECT_EQ(t.find("--missing"), nullptr);
  EXPECT_THROW(t.add("--count", count, "again"), Error);
  OptionTable other;
  other.add("--ratio", ratio, "clash");
  EXPECT_THROW(t.append(other), Error);
}

TEST(OptionTable, NumberListsAndSizesRefuseWhatIsNotThere) {
  EXPECT_EQ(parse_number_list("5,15,30", "--e"), (std::vector<double>{5, 15, 30}));
  EXPECT_EQ(parse_number_list("-1.5", "--e"), (std::vector<double>{-1.5}));
  for (const char* bad : {"", "1,", ",1", "1,,2", "nan", "1,inf", "1x", "one"}) {
    try {
      parse_number_list(bad, "--elevations");
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const Error& e) {
      EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
      EXPECT_NE(std::string(e.what()).find("--elevations"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(parse_finite_number("2.5", "--x", 0, 3), 2.5);
  for (const char* bad : {"", "nan", "inf", "2.5x", "4"}) EXPECT_THROW(parse_finite_number(bad, "--x", 0, 3), Error) << bad;
  EXPECT_EQ(parse_whole_number("-12", "--n"), -12);
  for (const char* bad : {"", "1.5", "99999999999999999999", "0x10", "0"})
    EXPECT_THROW(parse_whole_number(bad, "--n", 1, 100), Error) << bad;
  EXPECT_EQ(parse_image_size("640x480", "--size"), std::make_pair(640, 480));
  for (const char* bad : {"640", "640x", "x480", "0x480", "-640x480", "640x480x2", "640.5x480", "axb"})
    EXPECT_THROW(parse_image_size(bad, "--size"), Error) << bad;
}
