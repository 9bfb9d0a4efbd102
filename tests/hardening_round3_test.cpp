// Regression tests for issue #25 (hardening, round three): valid output that crashed us (a clip of
// empty frames), fields the checksums cover that were trusted without being checked (times,
// overlapping chunks, particle counts a file cannot justify), and temporaries on folders shared
// across PID namespaces. Every hostile file is made here: a cooked clip with one field changed
// and its checksums written again, so only the validator stands between it and the player.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <thread>

#include <fmt/format.h>

#include "base/output_file.hpp"
#include "hostile_inputs.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/stream.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

using test::expect_error;
using test::q;

template <typename T>
T get(const std::string& bytes, std::size_t at) {
  T v;
  std::memcpy(&v, bytes.data() + at, sizeof v);
  return v;
}
template <typename T>
void put(std::string& bytes, std::size_t at, T v) {
  std::memcpy(bytes.data() + at, &v, sizeof v);
}

// Writes the tables' and the header's checksums of a version 2 file again (docs/format.md:
// tables_offset at 128, tables_size at 136, tables_checksum at 144, header_checksum at 184).
void rechecksum(std::string& bytes) {
  const auto offset = get<std::uint64_t>(bytes, 128), size = get<std::uint64_t>(bytes, 136);
  put(bytes, 144, format::checksum(std::as_bytes(std::span(bytes.data() + offset, size))));
  put(bytes, 184, format::checksum(std::as_bytes(std::span(bytes.data(), 184))));
}

fs::path cook_clip(const fs::path& dir, const std::string& name, const std::string& codec, std::int64_t first = -1,
                   std::int64_t end = -1) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/" + name + ".abc");
  o.output = dir / (name + "-" + codec + ".pstream");
  o.chunk_size = format::kMinChunkSize;
  cook::set_codec(o, codec);
  if (first >= 0) {
    o.frame_begin = first;
    o.frame_end = end;
  }
  cook::cook(o);
  return o.output;
}

// ---- A clip of empty frames is a clip -----------------------------------------------------------

TEST(HardeningRound3, AClipOfEmptyFramesPlaysEverywhere) {
  const fs::path dir = test::fresh_dir();
  // Frames 12 and 13 of the fixture have no particles: the cook writes a valid clip of 0 chunks.
  // The particle codec cooks one too (it once failed: "an error bound of -inf"), and it plays.
  const fs::path particle = cook_clip(dir, "points_empty_frames", "particle", 12, 14);
  {
    const format::Reader r = format::Reader::open(particle);
    ASSERT_EQ(r.metadata().frame_count(), 2u);
    EXPECT_EQ(r.metadata().max_count, 0u);
    stream::StreamOptions options;
    options.blocking = true;
    auto s = stream::ParticleStream::open(particle, std::move(options));
    s->play();
    for (int i = 0; i < 5; ++i) {
      s->update(1.0 / 24);
      EXPECT_NE(s->state(), stream::PlayState::Error) << s->error();
      EXPECT_EQ(s->frame().count, 0u);
    }
  }
  const fs::path clip = cook_clip(dir, "points_empty_frames", "raw", 12, 14);
  const format::Reader reader = format::Reader::open(clip);
  ASSERT_EQ(reader.metadata().frame_count(), 2u);
  ASSERT_EQ(reader.metadata().chunk_count(), 0u);

  // The stream, blocking (offline rendering) and real time: every update returns, frames are empty.
  for (const bool blocking : {true, false}) {
    stream::StreamOptions options;
    options.blocking = blocking;
    auto s = stream::ParticleStream::open(clip, std::move(options));
    s->set_loop(true);
    s->play();
    for (int i = 0; i < 10; ++i) {
      s->update(1.0 / 24);
      EXPECT_NE(s->state(), stream::PlayState::Error) << s->error();
      EXPECT_EQ(s->frame().count, 0u);
    }
  }
  // The player, interpolating, with a sort.
  const std::vector<fs::path> files{clip};
  auto player = playback::Player::open(files);
  player->play();
  for (int i = 0; i < 10; ++i) {
    const auto& stats = player->advance(1.0 / 60, render::identity(), sort::SortMode::BackToFront);
    EXPECT_EQ(stats.particles, 0u);
  }
  player->check();

  // Every command: a correct (empty) result and exit code 0.
  for (const std::string& command :
       {fmt::format("verify {} --against {}", q(clip), q(test::data_path("alembic/points_empty_frames.abc"))),
        fmt::format("render {} --out {} -q", q(clip), q(dir / "frames")),
        fmt::format("bench stream {} --laps 1 --json", q(clip)),
        fmt::format("export {} -o {}", q(clip), q(dir / "e.abc")), fmt::format("info {} --json", q(clip))}) {
    // Mesa leaks a little at exit (see tests/CMakeLists.txt): no leak checking for render.
    const auto r = test::run_cli_raw(fmt::format(
        "{}{} {}", command.starts_with("render") ? "ASAN_OPTIONS=detect_leaks=0 " : "", PSTREAM_CLI, command));
    EXPECT_EQ(r.exit_code, 0) << command << "\n" << r.output;
  }
  EXPECT_TRUE(fs::exists(test::nth_frame(dir / "frames", 0)));
  const auto bench = test::run_cli(fmt::format("bench stream {} --laps 1 --json", q(clip)));
  EXPECT_NE(bench.output.find("\"stalls\":0"), std::string::npos) << bench.output;
  EXPECT_EQ(bench.output.find("null"), std::string::npos) << "a 0/0 figure: " << bench.output;
}

// ---- Times ------------------------------------------------------------------------------------

// Sample 1's .pointIds made to hold 4 ids for its 2 positions: sample 0's ids block is
// referenced in its place (the writer refuses to write such a sample). Every cook refuses it,
// whether it keeps ids or not.
TEST(HardeningRound3, MoreIdsThanParticlesIsRefusedByEveryCook) {
  const fs::path dir = test::fresh_dir();
  alembic::PointsWriterOptions o;
  o.velocities = false;
  {
    alembic::ArchiveWriter w(dir / "ids.abc", "test", "4 ids for 2 particles", 24.0, 0.0, o);
    const std::vector<float> P4 = {0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3}, P2 = {5, 5, 5, 6, 6, 6};
    const std::vector<std::uint64_t> ids4 = {9001, 9002, 9003, 9004}, ids2 = {7001, 7002};
    const std::vector<float> widths4 = {0.1f, 0.1f, 0.1f, 0.1f}, widths2 = {0.2f, 0.2f};
    w.write_sample({P4, ids4, {}, widths4, {}});
    w.write_sample({P2, ids2, {}, widths2, {}});
    w.close();
  }
  std::string bytes = test::read_file(dir / "ids.abc");
  // An array's data block: its size (8 bytes), a 16-byte digest, then the values.
  const auto block_ref = [&](std::uint64_t first_id) {
    const auto at = bytes.find(std::string(reinterpret_cast<const char*>(&first_id), 8));
    EXPECT_NE(at, std::string::npos);
    return static_cast<std::uint64_t>(at - 24) | (1ull << 63);
  };
  const std::uint64_t four = block_ref(9001), two = block_ref(7001);
  const auto ref_at = bytes.find(std::string(reinterpret_cast<const char*>(&two), 8));
  ASSERT_NE(ref_at, std::string::npos);
  std::memcpy(bytes.data() + ref_at, &four, 8);
  test::write_file(dir / "ids.abc", bytes);

  for (const char* codec : {"raw", "zstd", "particle"}) {
    SCOPED_TRACE(codec);
    expect_error(
        test::run_cli(fmt::format("cook {} --codec {} -o {}", q(dir / "ids.abc"), codec, q(dir / "o.pstream"))),
        "sample 1: 4 ids for 2 particles (.pointIds must hold one id per particle, or none)");
    EXPECT_FALSE(fs::exists(dir / "o.pstream"));
  }
}

// An Alembic object whose name is not valid UTF-8 (the writer's "particles", its first byte made
// 0xFF in every place the name is stored): info --json prints valid JSON with U+FFFD in its
// place, and the cook names it as it can.
TEST(HardeningRound3, NamesThatAreNotUtf8AreEscapedWherePrinted) {
  const fs::path dir = test::fresh_dir();
  alembic::PointsWriterOptions o;
  o.velocities = false;
  o.name = "particles";
  {
    alembic::ArchiveWriter w(dir / "name.abc", "test", "a name that is not UTF-8", 24.0, 0.0, o);
    const std::vector<float> P = {0, 0, 0, 1, 1, 1}, widths = {0.1f, 0.1f};
    const std::vector<std::uint64_t> ids = {1, 2};
    w.write_sample({P, ids, {}, widths, {}});
    w.close();
  }
  std::string bytes = test::read_file(dir / "name.abc");
  int patched = 0;
  for (std::size_t at = 0; (at = bytes.find("particles", at)) != std::string::npos; at += 9, ++patched)
    bytes[at] = '\xff';
  ASSERT_GT(patched, 0);
  test::write_file(dir / "name.abc", bytes);
  const auto info = test::run_cli("info " + q(dir / "name.abc") + " --json");
  ASSERT_EQ(info.exit_code, 0) << info.output;
  EXPECT_EQ(info.output.find("internal error"), std::string::npos) << info.output;
  EXPECT_NE(info.output.find("\xef\xbf\xbd"
                             "articles"),
            std::string::npos)
      << info.output;  // U+FFFD, UTF-8
  const auto text = test::run_cli("info " + q(dir / "name.abc"));
  EXPECT_EQ(text.exit_code, 0) << text.output;
  const auto cook = test::run_cli("cook " + q(dir / "name.abc") + " -q -o " + q(dir / "o.pstream"));
  EXPECT_EQ(cook.output.find("internal error"), std::string::npos) << cook.output;
}

TEST(HardeningRound3, HeaderTimesMustBeFiniteAndOnTheFramesGrid) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = cook_clip(dir, "points_constant", "raw");
  const std::string good = test::read_text(clip);
  for (const double bad : {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                           -std::numeric_limits<double>::infinity(), 1e300}) {
    std::string bytes = good;
    put(bytes, 32, bad);  // time_of_frame0
    rechecksum(bytes);
    test::write_file(dir / "bad.pstream", bytes);
    expect_error(test::run_cli("verify " + q(dir / "bad.pstream")), "time_of_frame0 is");
    expect_error(test::run_cli(fmt::format("render {} --out {} -q", q(dir / "bad.pstream"), q(dir / "frames"))),
                 "time_of_frame0 is");
    EXPECT_THROW(stream::ParticleStream::open(dir / "bad.pstream"), Error);
  }
  // A finite origin that the frame index does not follow: playback would pick frames by a grid
  // the frames are not on.
  std::string bytes = good;
  put(bytes, 32, get<double>(good, 32) + 10.0);
  rechecksum(bytes);
  test::write_file(dir / "off_grid.pstream", bytes);
  expect_error(test::run_cli("verify " + q(dir / "off_grid.pstream")), "(time_of_frame0");
}

// ---- Chunks that share bytes, and counts the bytes cannot hold ------------------------------------

TEST(HardeningRound3, ChunksMustBeDisjointAndHoldWhatTheyClaim) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = cook_clip(dir, "points_large", "zstd");
  const format::Metadata m = format::Reader::open(clip).metadata();
  ASSERT_GE(m.chunk_count(), 3u);
  const std::string good = test::read_text(clip);
  const std::size_t table = get<std::uint64_t>(good, 128) + get<std::uint64_t>(good, 136) - 32 * m.chunk_count();
  ASSERT_EQ(get<std::uint64_t>(good, table), m.chunks[0].file_offset);  // the chunk table is last

  // Chunk 1 pointing at chunk 0's bytes.
  std::string shared = good;
  put(shared, table + 32, m.chunks[0].file_offset);
  put(shared, table + 32 + 8, m.chunks[0].stored_size);
  rechecksum(shared);
  test::write_file(dir / "shared.pstream", shared);
  expect_error(test::run_cli("verify " + q(dir / "shared.pstream")), "inside the chunk before it");

  // A 64 KiB raw chunk claimed from 16 stored bytes.
  const fs::path raw = cook_clip(dir, "points_large", "raw");
  const format::Metadata mr = format::Reader::open(raw).metadata();
  std::string tiny = test::read_text(raw);
  const std::size_t raw_table = get<std::uint64_t>(tiny, 128) + get<std::uint64_t>(tiny, 136) - 32 * mr.chunk_count();
  put(tiny, raw_table + 8, std::uint64_t{16});
  rechecksum(tiny);
  test::write_file(dir / "tiny.pstream", tiny);
  expect_error(test::run_cli("verify " + q(dir / "tiny.pstream")), "expected at most 16 from raw data");

  EXPECT_EQ(format::max_decoded_size(format::Codec::Raw, 100), 100u);
  EXPECT_EQ(format::max_decoded_size(format::Codec::Zstd, 10), 327680u);
  EXPECT_EQ(format::max_decoded_size(format::Codec::Zstd, UINT64_MAX), UINT64_MAX);  // saturates
}

TEST(HardeningRound3, AParticleCountTheFileCannotJustifyIsRefusedBeforeAllocating) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = cook_clip(dir, "points_constant", "particle");
  std::string bytes = test::read_text(clip);
  const format::Metadata m = format::Reader::open(clip).metadata();
  ASSERT_LT(bytes.size(), 1u << 20);
  // max_count 2^26 (the particle codec's limit) in the header and in the last frame's index entry
  // (the frame index must agree with the header; the last frame's count moves no later offset).
  put(bytes, 88, std::uint64_t{1} << 26);
  const format::FrameEntry& last = m.frames.back();
  const std::size_t tables = get<std::uint64_t>(bytes, 128);
  std::size_t at = tables;
  for (; at + 16 <= bytes.size(); ++at) {
    if (get<std::uint64_t>(bytes, at) == last.count && get<std::uint64_t>(bytes, at + 8) == last.byte_offset) break;
  }
  ASSERT_LT(at + 16, bytes.size());
  put(bytes, at, std::uint64_t{1} << 26);
  rechecksum(bytes);
  test::write_file(dir / "claims.pstream", bytes);

  // Refused at open, with the field and what it would need, and no allocation of gigabytes (the
  // address-space limit below would turn one into a crash).
  try {
    stream::ParticleStream::open(dir / "claims.pstream");
    ADD_FAILURE() << "opened";
  } catch (const OptionError& e) {
    EXPECT_EQ(e.option(), "budget");
    EXPECT_NE(std::string(e.what()).find("max_count 67108864 particles"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("claims.pstream"), std::string::npos) << e.what();
  }
#ifdef PSTREAM_SANITIZED
  const std::string limit;  // ASan reserves terabytes of address space
#else
  const std::string limit = "ulimit -v 1048576; ";  // 1 GiB
#endif
  const auto r = test::run_cli_raw(fmt::format("{}{} verify {}", limit, PSTREAM_CLI, q(dir / "claims.pstream")));
  expect_error(r, "max_count 67108864 particles");
  // A host that sets a budget decides: too small a budget is still an error naming it.
  stream::StreamOptions options;
  options.budget = std::make_shared<stream::MemoryBudget>(64 << 20);
  EXPECT_THROW(stream::ParticleStream::open(dir / "claims.pstream", std::move(options)), OptionError);
}

// ---- Values a cook must not take silently ---------------------------------------------------------

TEST(HardeningRound3, NanInfiniteOrNegativeWidthsAreRefusedOrDropped) {
  const fs::path dir = test::fresh_dir();
  constexpr std::size_t n = 40;
  std::vector<float> positions(n * 3), widths(n, 0.1f);
  for (std::size_t i = 0; i < n * 3; ++i) positions[i] = float(i) * 0.01f;
  widths[3] = std::numeric_limits<float>::quiet_NaN();
  widths[17] = -0.5f;
  widths[31] = std::numeric_limits<float>::infinity();
  for (const std::string extra : {"", " --attributes id"}) {  // the direct path, and the general one
    fs::remove(dir / "out.pstream");
    std::vector<std::uint64_t> ids(n);
    for (std::size_t i = 0; i < n; ++i) ids[i] = i;
    alembic::PointsWriterOptions po;
    po.widths = true;
    po.velocities = false;
    {
      alembic::ArchiveWriter w(dir / "in.abc", "test", "bad widths", 24.0, 0.0, po);
      alembic::PointsSample sample;
      sample.positions = positions;
      sample.ids = ids;
      sample.widths = widths;
      w.write_sample(sample);
      w.write_sample(sample);
      w.close();
    }
    expect_error(test::run_cli(fmt::format("cook {} -o {} -q{}", q(dir / "in.abc"), q(dir / "out.pstream"), extra)),
                 "frame 0: 3 particles have a NaN, infinite or negative size (the first is particle 3, size nan); "
                 "--drop-invalid drops them");
    EXPECT_FALSE(fs::exists(dir / "out.pstream"));
    const auto r = test::run_cli(
        fmt::format("cook {} -o {} -q --drop-invalid{}", q(dir / "in.abc"), q(dir / "out.pstream"), extra));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const format::Reader reader = format::Reader::open(dir / "out.pstream");
    EXPECT_EQ(reader.metadata().frames[0].count, n - 3);
    std::vector<std::byte> records = format::frame_buffer(reader.metadata(), reader.name());
    reader.read_frame(0, records);
    for (std::size_t i = 0; i < n - 3; ++i) {
      const float s = get<float>(std::string(reinterpret_cast<const char*>(records.data()), records.size()),
                                 i * reader.metadata().record_size + render::kScaleOffset);
      EXPECT_EQ(s, 0.05f) << "particle " << i;
    }
  }
}

TEST(HardeningRound3, AnUnknownRampAttributeIsRefusedBeforeRendering) {
  const fs::path dir = test::fresh_dir();
  const std::string clip = test::data_path("pstream_v1/points_varying_lz4.pstream");
  const auto r =
      test::run_cli_raw(fmt::format("ASAN_OPTIONS=detect_leaks=0 {} render {} --out {} -q --ramp-attribute nope",
                                    PSTREAM_CLI, q(clip), q(dir / "frames")));
  expect_error(r, "--ramp-attribute 'nope' is not one of its float attributes");
  EXPECT_FALSE(fs::exists(test::nth_frame(dir / "frames", 0)));
}

TEST(HardeningRound3, NamesAreDataNotSyntaxInExportedPly) {
  const fs::path dir = test::fresh_dir();
  format::Metadata meta;
  meta.fps = 24;
  meta.chunk_size = format::kMinChunkSize;
  meta.layout = format::default_layout();
  meta.record_size = format::append_attribute(meta.layout, "two words", format::AttributeType::Float32, 1);
  meta.source_file = "a.abc\nproperty float injected";
  meta.source_object = "/obj\nend_header";
  {
    format::Writer writer(dir / "names.pstream", meta);
    writer.append_frame(1, 0.0, {0, 0, 0, 0, 0, 0});
    const float record[5] = {0, 0, 0, 0.1f, 7.0f};
    const auto raw = std::as_bytes(std::span(record));
    writer.append_chunk(raw, format::Codec::Raw, 0, format::checksum(raw));
    writer.commit();
  }
  expect_error(test::run_cli(fmt::format("export {} --out {} -q", q(dir / "names.pstream"), q(dir / "ply"))),
               "the attribute \"two words\" cannot be a PLY property name");
  EXPECT_FALSE(fs::exists(dir / "ply"));
  // A name with a control character is refused where a layout is made, and by the reader.
  std::vector<format::Attribute> layout = format::default_layout();
  EXPECT_THROW(format::append_attribute(layout, "bad\nname", format::AttributeType::Float32, 1), Error);
  // Source names with line breaks are escaped in the PLY header's comment: one line, no injection.
  format::Metadata plain = meta;
  plain.layout = format::default_layout();
  plain.record_size = 16;
  {
    format::Writer writer(dir / "plain.pstream", plain);
    writer.append_frame(1, 0.0, {0, 0, 0, 0, 0, 0});
    const float record[4] = {0, 0, 0, 0.1f};
    const auto raw = std::as_bytes(std::span(record));
    writer.append_chunk(raw, format::Codec::Raw, 0, format::checksum(raw));
    writer.commit();
  }
  ASSERT_EQ(test::run_cli(fmt::format("export {} --out {} -q", q(dir / "plain.pstream"), q(dir / "ply2"))).exit_code,
            0);
  const std::string ply = test::read_text(dir / "ply2" / "frame.0001.ply");
  EXPECT_EQ(ply.find("\nproperty float injected"), std::string::npos) << ply.substr(0, 300);
  EXPECT_EQ(ply.find("\nend_header"), ply.rfind("\nend_header"));
  EXPECT_NE(ply.find("a.abc\\x0aproperty float injected"), std::string::npos) << ply.substr(0, 300);
}

TEST(HardeningRound3, AVideoHoldsExactlyTheFramesOfThisRender) {
  if (test::run_cli_raw("ffprobe -version").exit_code != 0) GTEST_SKIP() << "no ffprobe";
  const fs::path dir = test::fresh_dir();
  const std::string clip = test::data_path("pstream_v1/points_varying_lz4.pstream");
  const auto render = [&](const std::string& frames) {
    return test::run_cli_raw(
        fmt::format("ASAN_OPTIONS=detect_leaks=0 {} render {} --out {} --video {} --frames {} -q "
                    "--size 160x90",
                    PSTREAM_CLI, q(clip), q(dir / "frames"), q(dir / "v.mp4"), frames));
  };
  ASSERT_EQ(render("0:30").exit_code, 0);  // 30 frames in the folder
  const auto second = render("0:8");       // then 8 into the same folder
  ASSERT_EQ(second.exit_code, 0) << second.output;
  const auto probe = test::run_cli_raw(fmt::format(
      "ffprobe -v error -count_frames -select_streams v:0 -show_entries stream=nb_read_frames -of csv=p=0 {}",
      q(dir / "v.mp4")));
  EXPECT_EQ(std::stoi(probe.output), 8) << "the video took older frames from the folder: " << probe.output;
}

// ---- Temporaries on shared folders ------------------------------------------------------------------

bool has_temporary(const fs::path& dir) {
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().filename().string().find(".partial-") != std::string::npos) return true;
  }
  return false;
}

TEST(HardeningRound3, ACookInAnotherPidNamespaceNeverDeletesALiveTemporary) {
  if (::geteuid() != 0 || test::run_cli_raw("unshare --pid --fork true").exit_code != 0) {
    GTEST_SKIP() << "needs root and unshare (CI runs as root)";
  }
  const fs::path dir = test::fresh_dir();
  // This process writes an output; its temporary is live.
  OutputFile mine = OutputFile::create(dir / "mine.pstream");
  mine.append(std::string(4096, 'x').data(), 4096);
  ASSERT_TRUE(has_temporary(dir));
  // A cook in a new PID namespace, where this process's id means nothing (it once decided "dead"
  // from kill(pid, 0) and deleted the temporary), writes into the same folder.
  const auto r =
      test::run_cli_raw(fmt::format("unshare --pid --fork {} cook {} -o {} -q", PSTREAM_CLI,
                                    q(test::data_path("alembic/points_constant.abc")), q(dir / "theirs.pstream")));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(mine.temporary())) << "a live temporary was deleted";
  EXPECT_EQ(mine.commit(), 4096u);
  EXPECT_EQ(fs::file_size(dir / "mine.pstream"), 4096u);
}

TEST(HardeningRound3, ConcurrentWritersInOneFolderNeverRemoveEachOthersTemporaries) {
  // Every writer cleans the folder of stale temporaries when it starts; none may take another's
  // live one (a lock released before the rename once let a cleanup remove it: "cannot rename").
  const fs::path dir = test::fresh_dir();
  std::vector<std::thread> writers;
  std::atomic<int> failures{0};
  for (int w = 0; w < 4; ++w) {
    writers.emplace_back([&, w] {
      for (int k = 0; k < 150; ++k) {
        try {
          OutputFile out = OutputFile::create(dir / fmt::format("w{}-{}.bin", w, k));
          out.append("0123456789abcdef", 16);
          out.commit();
        } catch (const Error&) {
          ++failures;
        }
      }
    });
  }
  for (auto& t : writers) t.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_FALSE(has_temporary(dir));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator{}), 600);
}

TEST(HardeningRound3, ASigkilledWritersTemporaryIsRemovedByTheNextWriter) {
  const fs::path dir = test::fresh_dir();
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    OutputFile out = OutputFile::create(dir / "killed.pstream");
    out.append(std::string(1 << 16, 'x').data(), 1 << 16);
    out.write_at(0, std::as_bytes(std::span("x", 1)));
    ::raise(SIGKILL);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));
  ASSERT_TRUE(has_temporary(dir)) << "SIGKILL leaves the temporary";
  test::write_file(dir / ".notes.partial-draft", "a user's file that only looks similar");
  ASSERT_EQ(test::run_cli(fmt::format("cook {} -o {} -q", q(test::data_path("alembic/points_constant.abc")),
                                      q(dir / "next.pstream")))
                .exit_code,
            0);
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    EXPECT_TRUE(name == "next.pstream" || name == ".notes.partial-draft") << "left: " << name;
  }
}

TEST(HardeningRound3, TemporariesFitNameMax) {
  const fs::path dir = test::fresh_dir();
  const std::string name = std::string(254, 'n');  // a valid name, one short of NAME_MAX
  const fs::path output = dir / name;
  {
    OutputFile out = OutputFile::create(output);
    EXPECT_LE(out.temporary().filename().string().size(), 255u);
    out.append(std::string("abc").data(), 3);
    out.commit();
  }
  EXPECT_EQ(fs::file_size(output), 3u);
  const auto r = test::run_cli(
      fmt::format("cook {} -o {} -q", q(test::data_path("alembic/points_constant.abc")), q(dir / (name + "x"))));
  // 255 characters: the longest name there is.
  EXPECT_EQ(r.exit_code, 0) << r.output;
}

}  // namespace
