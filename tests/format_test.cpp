// The .pstream reader on damaged files: every corruption gives a clear error naming the file and
// the field, never a crash or a wrong frame.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>

#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "test_util.hpp"

#include <nlohmann/json.hpp>

namespace {

using namespace pstream;
namespace fs = std::filesystem;

std::vector<std::byte> cooked_bytes() {
  static const std::vector<std::byte> bytes = [] {
    const fs::path dir = test::fresh_dir();  // per test: CTest runs tests in parallel processes
    cook::Options o;
    o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
    o.input = test::data_path("alembic/points_constant.abc");
    o.output = dir / "clip.pstream";
    o.chunk_size = format::kMinChunkSize;
    o.codec = format::Codec::Lz4;
    cook::cook(o);
    return test::read_bytes(o.output);
  }();
  return bytes;
}

template <class T>
T get(const std::vector<std::byte>& b, std::size_t at) {
  T v;
  std::memcpy(&v, b.data() + at, sizeof v);
  return v;
}
template <class T>
void put(std::vector<std::byte>& b, std::size_t at, T v) {
  std::memcpy(b.data() + at, &v, sizeof v);
}

// Recomputes the tables and header checksums, so a test reaches the check it targets.
void reseal(std::vector<std::byte>& b) {
  const auto tables_offset = get<std::uint64_t>(b, 128), tables_size = get<std::uint64_t>(b, 136);
  put(b, 144, format::checksum(std::span(b).subspan(tables_offset, tables_size)));
  put(b, 184, format::checksum(std::span(b).first(184)));  // version 2's header checksum
}

std::string open_error(const std::vector<std::byte>& bytes) {
  try {
    const auto r = format::Reader::from_memory(bytes, "clip.pstream");
    std::vector<std::byte> scratch(r.metadata().chunk_size);
    for (std::uint64_t c = 0; c < r.metadata().chunk_count(); ++c) r.read_chunk(c, scratch);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void expect_error(const std::vector<std::byte>& bytes, const std::string& fragment) {
  const std::string m = open_error(bytes);
  EXPECT_NE(m.find("clip.pstream"), std::string::npos) << m;
  EXPECT_NE(m.find(fragment), std::string::npos) << "message: " << m;
}

TEST(FormatCorruption, IntactFileReads) { EXPECT_EQ(open_error(cooked_bytes()), ""); }

TEST(FormatCorruption, FlippedByteInAChunk) {
  auto b = cooked_bytes();
  const auto r = format::Reader::from_memory(b, "x");
  const auto at = r.metadata().chunks[3].file_offset + 10;
  b[at] ^= std::byte{0x40};
  expect_error(b, "chunk 3 (file offset");
  expect_error(b, "checksum mismatch");
}

TEST(FormatCorruption, TruncatedFile) {
  const auto full = cooked_bytes();
  for (std::size_t size : {std::size_t{0}, std::size_t{7}, std::size_t{100}, full.size() / 2, full.size() - 1}) {
    const std::vector<std::byte> cut(full.begin(), full.begin() + static_cast<std::ptrdiff_t>(size));
    EXPECT_FALSE(open_error(cut).empty()) << size;
  }
  const std::vector<std::byte> half(full.begin(), full.begin() + static_cast<std::ptrdiff_t>(full.size() / 2));
  expect_error(half, "outside the file");
}

TEST(FormatCorruption, WrongMagicAndVersion) {
  auto b = cooked_bytes();
  b[0] = std::byte{'X'};
  expect_error(b, "not a .pstream file");
  b = cooked_bytes();
  put<std::uint32_t>(b, 8, 7);
  expect_error(b, "unsupported format version 7 (this build reads versions 1 to 6)");
  b = cooked_bytes();
  b[30] ^= std::byte{1};  // inside fps
  expect_error(b, "header checksum mismatch");
}

TEST(FormatCorruption, ChunkTablePointingPastTheEnd) {
  auto b = cooked_bytes();
  const auto m = format::Reader::from_memory(b, "x").metadata();
  // The chunk table is the last part of the tables: entry 2's file_offset.
  const std::size_t entry = get<std::uint64_t>(b, 128) + get<std::uint64_t>(b, 136) - (m.chunk_count() - 2) * 32;
  put<std::uint64_t>(b, entry, b.size() + 4096);
  reseal(b);
  expect_error(b, "chunk 2 lies at bytes");
  expect_error(b, "points past the end");
}

TEST(FormatCorruption, FrameIndexInconsistent) {
  auto b = cooked_bytes();
  const auto m = format::Reader::from_memory(b, "x").metadata();
  const std::size_t frames =
      get<std::uint64_t>(b, 128) + get<std::uint64_t>(b, 136) - m.chunk_count() * 32 - m.frame_count() * 64;
  put<std::uint64_t>(b, frames + 5 * 64 + 8, 12345);  // frame 5's byte offset
  reseal(b);
  expect_error(b, "frame 5 starts at byte 12345");
  expect_error(b, "frame index inconsistent");
}

TEST(FormatCorruption, TablesChecksum) {
  auto b = cooked_bytes();
  b[get<std::uint64_t>(b, 128) + 40] ^= std::byte{2};
  expect_error(b, "tables checksum mismatch");
}

TEST(FormatCorruption, VerifyCommandExitCodes) {
  const fs::path dir = test::fresh_dir();
  auto b = cooked_bytes();
  const auto write = [&](const fs::path& p) {
    std::FILE* f = std::fopen(p.c_str(), "wb");
    std::fwrite(b.data(), 1, b.size(), f);
    std::fclose(f);
  };
  write(dir / "good.pstream");
  auto r = test::run_cli("verify '" + (dir / "good.pstream").string() + "'");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("OK"), std::string::npos);
  const auto m = format::Reader::from_memory(b, "x").metadata();
  b[m.chunks[1].file_offset] ^= std::byte{1};
  write(dir / "bad.pstream");
  r = test::run_cli("verify '" + (dir / "bad.pstream").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("chunk 1"), std::string::npos) << r.output;
}

TEST(Format, MetadataRoundTrips) {
  const auto b = cooked_bytes();
  const auto m = format::parse_metadata(b, "x");
  const auto tables = format::serialize_tables(m);
  const auto header = format::serialize_header(m, get<std::uint64_t>(b, 128), tables);
  ASSERT_EQ(header.size(), format::kHeaderSize);
  EXPECT_EQ(std::memcmp(header.data(), b.data(), header.size()), 0);
  EXPECT_EQ(std::memcmp(tables.data(), b.data() + get<std::uint64_t>(b, 128), tables.size()), 0);
  EXPECT_EQ(m.frame_count(), 48u);
  EXPECT_EQ(m.max_count, 1000u);
  EXPECT_DOUBLE_EQ(m.fps, 24.0);
}

TEST(Format, InfoJsonFrameSumsMatchTheSource) {
  const fs::path dir = test::fresh_dir();
  const std::string out = (dir / "v.pstream").string();
  auto r = test::run_cli("cook -q '" + test::data_path("alembic/points_varying.abc") + "' -o '" + out +
                         "' --chunk-size 64KiB --codec raw");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("info --json --frames '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output);
  const auto expected = nlohmann::json::parse(test::read_text(test::data_path("alembic/points_varying.expected.json")));
  ASSERT_EQ(j["frames"].size(), 60u);
  for (std::size_t f = 0; f < 60; ++f) {
    const auto& e = expected["points"][0]["samples"][f];
    EXPECT_EQ(j["frames"][f]["count"], e["count"]);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(j["frames"][f]["sum"][c].get<double>(), e["positions"]["sum"][c].get<double>(),
                  1e-9 * std::max(1.0, std::abs(e["positions"]["sum"][c].get<double>())));
    }
    EXPECT_NEAR(j["frames"][f]["sum"][3].get<double>(), e["widths"]["vals"]["sum"].get<double>() / 2, 1e-9);
  }
}

}  // namespace
