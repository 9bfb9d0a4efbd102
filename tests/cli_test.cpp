// The command line a user types: typos get "did you mean" (issue #27's first CLI item).
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "particlestream/alembic_writer.hpp"
#include "particlestream/demo.hpp"
#include "particlestream/format.hpp"
#include "test_util.hpp"

namespace {

using pstream::test::run_cli;

void expect_suggestion(const std::string& args, const std::string& message) {
  const auto r = run_cli(args);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find(message), std::string::npos) << "expected '" << message << "' in:\n" << r.output;
}

TEST(Cli, TyposGetDidYouMean) {
  expect_suggestion("rendr x.pstream", "unknown command `rendr`; did you mean `render`?");
  expect_suggestion("bench strem", "unknown command `strem`; did you mean `stream`?");
  expect_suggestion("cook --codc particle x.abc", "unknown option --codc; did you mean --codec?");
  expect_suggestion("render x.pstream --presett smoke", "unknown option --presett; did you mean --preset?");
  expect_suggestion("cook --helpp", "did you mean --help?");
  // Two letters the wrong way round are one typo, as one wrong letter is.
  expect_suggestion("cook x.abc --erorr 1e-4", "unknown option --erorr; did you mean --error?");
  expect_suggestion("redner x.pstream", "unknown command `redner`; did you mean `render`?");
  // Far from every name: said plainly, with where to look.
  expect_suggestion("cook x.abc --zzzzzzzz", "unknown option --zzzzzzzz for `cook` (see its --help)");
  // A short option the command lacks (render writes to --out, where cook has -o): named, with the
  // long options that begin with its letter, rather than a complaint about the argument after it.
  expect_suggestion("render x.pstream -o frames", "unknown option -o; did you mean --out or --opacity?");
  expect_suggestion("render x.pstream -f 1:2", "unknown option -f for `render` (see its --help)");
  {
    // Negative numbers are values, not options.
    const auto value = run_cli("render /no/such/x.pstream --camera -3,2,1:0,0,0");
    EXPECT_EQ(value.output.find("unknown option"), std::string::npos) << value.output;
  }
  // Choices the library parses: its message, with the nearest choice.
  const std::string abc = pstream::test::data_path("alembic/points_constant.abc");
  const auto codec = run_cli("cook '" + abc + "' -o /nonexistent/dir/x.pstream --codec partcle");
  EXPECT_NE(codec.output.find("--codec 'partcle': expected particle"), std::string::npos) << codec.output;
  EXPECT_NE(codec.output.find("(did you mean 'particle'?)"), std::string::npos) << codec.output;
  const auto look = run_cli("render '" + pstream::test::data_path("pstream_v1/points_varying_lz4.pstream") +
                            "' --out /nonexistent/dir -q --look liqud");
  EXPECT_NE(look.output.find("look 'liqud': expected sprites or liquid (did you mean 'liquid'?)"), std::string::npos)
      << look.output;
  // Known words still parse (and fail, here, on the missing file, as before).
  const auto r = run_cli("info /no/such/file.abc");
  EXPECT_NE(r.output.find("/no/such/file.abc"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("did you mean"), std::string::npos) << r.output;
}

// A command that needs a subcommand, given none, shows what it offers (exit code 2).
TEST(Cli, ACommandAloneListsItsSubcommands) {
  const auto top = run_cli("");
  EXPECT_EQ(top.exit_code, 2) << top.output;
  for (const char* word : {"Typical use:", "Subcommands:", "  cook ", "  export ", "  render ", "  bench "})
    EXPECT_NE(top.output.find(word), std::string::npos) << word << " in:\n" << top.output;
  const auto bench = run_cli("bench");
  EXPECT_EQ(bench.exit_code, 2) << bench.output;
  for (const char* word : {"Measure a stage", "  codec ", "  sort ", "  playback "})
    EXPECT_NE(bench.output.find(word), std::string::npos) << word << " in:\n" << bench.output;
  EXPECT_EQ(bench.output.find("Typical use:"), std::string::npos) << bench.output;  // bench's own, not the top's
}

}  // namespace

namespace {

// export: a clip with empty frames round-trips through Alembic and through PLY exactly, and so
// does the Blender sparks fixture (births and deaths, ids, colours, velocities); -o's extension
// chooses the format (.ply a sequence), and another extension is refused with nothing written.
TEST(Cli, ExportRoundTripsEmptyFramesAndTheExtensionChoosesTheFormat) {
  namespace fs = std::filesystem;
  const fs::path dir = pstream::test::fresh_dir();
  const std::string abc = pstream::test::data_path("alembic/points_empty_frames.abc");
  using pstream::test::q;
  // Every frame's count and sums (info --json --frames: float64 sums of x y z scale).
  const auto frames = [&](const fs::path& clip) {
    const auto j = nlohmann::json::parse(run_cli("info --json --frames " + q(clip)).output);
    return j["frames"];
  };
  std::size_t empty = 0;
  // An explosion as a studio cache holds one: no particles for its first frames, then a burst that
  // dies out (the demo's simulator, written by our Alembic writer with ids, velocities, widths, Cd).
  // ../shared has no explosion fixture; this stands in for it.
  const fs::path explosion = dir / "explosion.abc";
  {
    pstream::demo::Simulator sim({"explosion", 3000, 2.0, 24.0, 3, 1});
    pstream::alembic::PointsWriterOptions po;
    po.name = "explosion";
    po.float_params = {{"Cd", 4}};
    pstream::alembic::ArchiveWriter writer(explosion, "cli_test", "explosion", 24.0, 1.0 / 24.0, po);
    for (int k = 0; k < 3; ++k) writer.write_sample({{}, {}, {}, {}, {std::span<const float>{}}});  // before the burst
    for (std::uint64_t f = 0; f < sim.frame_count(); ++f) {
      sim.step();
      const pstream::demo::ParticleState& st = sim.state();
      writer.write_sample({st.position, st.id, st.velocity, st.width, {st.color}});
    }
    writer.close();
  }
  for (const auto& [source, extra] : {std::pair<std::string, std::string>{abc, ""},
                                      {pstream::test::data_path("sims/blender_sparks.abc"), " --attributes id"},
                                      {explosion.string(), " --attributes id"}}) {
    const fs::path sub = dir / fs::path(source).stem();
    fs::create_directories(sub);
    ASSERT_EQ(run_cli("cook -q --codec raw" + extra + " " + q(source) + " -o " + q(sub / "clip.pstream")).exit_code, 0);
    auto r = run_cli("export -q " + q(sub / "clip.pstream") + " -o " + q(sub / "back.abc"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    r = run_cli("export -q " + q(sub / "clip.pstream") + " -o " + q(sub / "seq" / "fx.ply"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_TRUE(fs::exists(sub / "seq" / "fx.0001.ply"));
    r = run_cli("cook -q --codec raw" + extra + " " + q(sub / "back.abc") + " -o " + q(sub / "from_abc.pstream"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    r = run_cli("cook -q --codec raw" + extra + " " + q(sub / "seq" / "fx.0001.ply") + " --fps 24 -o " +
                q(sub / "from_ply.pstream"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const auto original = frames(sub / "clip.pstream");
    // info on any file of the PLY sequence describes the whole of it: one file a frame, each with
    // its frame's count.
    r = run_cli("info --json " + q(sub / "seq" / "fx.0002.ply"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const auto ply = nlohmann::json::parse(r.output);
    EXPECT_EQ(ply["format"], "ply");
    EXPECT_EQ(ply["encoding"], "binary_little_endian");
    EXPECT_EQ(ply["first_number"], 1);
    ASSERT_EQ(ply["files"].size(), original.size());
    for (std::size_t f = 0; f < original.size(); ++f)
      EXPECT_EQ(ply["files"][f]["count"], original[f]["count"]) << "frame " << f;
    EXPECT_EQ(ply["properties"][3]["name"], "pscale");
    EXPECT_EQ(ply["cook"]["scale_from"], "pscale");
    for (const fs::path& copy : {sub / "from_abc.pstream", sub / "from_ply.pstream"}) {
      const auto back = frames(copy);
      ASSERT_EQ(back.size(), original.size()) << copy;
      for (std::size_t f = 0; f < original.size(); ++f) {
        EXPECT_EQ(back[f]["count"], original[f]["count"]) << copy << " frame " << f;
        EXPECT_EQ(back[f]["sum"], original[f]["sum"]) << copy << " frame " << f;
        empty += original[f]["count"] == 0;
      }
    }
    // The records themselves, ids and colours included, equal the clip's at every frame.
    for (const fs::path& copy : {sub / "from_abc.pstream", sub / "from_ply.pstream"}) {
      const auto a = pstream::format::Reader::open(sub / "clip.pstream");
      const auto b = pstream::format::Reader::open(copy);
      ASSERT_EQ(a.metadata().record_size, b.metadata().record_size) << copy;
      std::vector<std::byte> ra = pstream::format::frame_buffer(a.metadata(), a.name());
      std::vector<std::byte> rb = pstream::format::frame_buffer(b.metadata(), b.name());
      for (std::uint64_t f = 0; f < a.metadata().frame_count(); ++f) {
        a.read_frame(f, ra);
        b.read_frame(f, rb);
        const std::size_t n = a.metadata().frames[f].count * a.metadata().record_size;
        EXPECT_EQ(std::memcmp(ra.data(), rb.data(), n), 0) << copy << " frame " << f;
      }
    }
  }
  EXPECT_GT(empty, 0u) << "the fixture's empty frames";
  // Writing over the clip's own source (its name and content hash, as the cook recorded them) is
  // refused, and the source is left as it was.
  fs::copy_file(abc, dir / "points_empty_frames.abc");
  auto r = run_cli("export -q " + q(dir / "points_empty_frames" / "clip.pstream") + " -o " +
                   q(dir / "points_empty_frames.abc"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("is the source"), std::string::npos) << r.output;
  EXPECT_EQ(fs::file_size(dir / "points_empty_frames.abc"), fs::file_size(abc));
  r = run_cli("export -q " + q(dir / "points_empty_frames" / "clip.pstream") + " -o " + q(dir / "x.txt"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("the extension chooses the format"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "x.txt"));
  // A sequence with a file missing is named as the cook names it; a URL is refused.
  fs::remove(dir / "blender_sparks" / "seq" / "fx.0003.ply");
  r = run_cli("info " + q(dir / "blender_sparks" / "seq" / "fx.0001.ply"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("fx.####.ply: frame 3 is missing (between fx.0002.ply and fx.0004.ply)"), std::string::npos)
      << r.output;
  r = run_cli("info http://127.0.0.1:9/x.0001.ply");
  EXPECT_NE(r.output.find("a PLY sequence is read from local files"), std::string::npos) << r.output;
  // --out DIR is DIR/frame.NNNN.ply; --json says what was written, for scripts.
  const fs::path clip = dir / "points_empty_frames" / "clip.pstream";
  r = run_cli("export --json " + q(clip) + " --out " + q(dir / "plys"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output);
  const auto frame_count = pstream::format::Reader::open(clip).metadata().frame_count();
  EXPECT_EQ(j["format"], "ply");
  EXPECT_EQ(j["frames"], frame_count);
  EXPECT_EQ(j["first"], (dir / "plys" / "frame.0001.ply").string());
  std::uint64_t bytes = 0;
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir / "plys")) bytes += fs::file_size(e.path()), ++files;
  EXPECT_EQ(files, frame_count);
  EXPECT_EQ(j["bytes_written"], bytes);
  // --frames A:B: a part, the files numbered as their frames.
  r = run_cli("export --json --frames 1:3 " + q(clip) + " -o " + q(dir / "part" / "p.ply"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(nlohmann::json::parse(r.output)["frames"], 2);
  EXPECT_TRUE(fs::exists(dir / "part" / "p.0002.ply") && fs::exists(dir / "part" / "p.0003.ply"));
  EXPECT_FALSE(fs::exists(dir / "part" / "p.0001.ply") || fs::exists(dir / "part" / "p.0004.ply"));
  // --frames N: frame N alone.
  r = run_cli("export --json --frames 2 " + q(clip) + " -o " + q(dir / "one" / "p.ply"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(nlohmann::json::parse(r.output)["frames"], 1);
  EXPECT_TRUE(fs::exists(dir / "one" / "p.0003.ply"));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir / "one"), fs::directory_iterator{}), 1);
  // A file where the sequence's folder would be is named, and nothing is written.
  std::ofstream(dir / "taken") << "a file";
  r = run_cli("export -q " + q(clip) + " -o " + q(dir / "taken" / "f.ply"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("taken: exists and is not a folder"), std::string::npos) << r.output;
}

}  // namespace

namespace {

// info says when an Alembic cache has ids in name only (Blender's FLIP writes empty .pointIds).
TEST(Cli, InfoSaysWhenIdsAreEmpty) {
  const auto flip = run_cli("info '" + pstream::test::data_path("sims/blender_flip_pour_small.abc") + "'");
  EXPECT_NE(flip.output.find(".pointIds      uint64      varying  empty: written without ids"), std::string::npos)
      << flip.output;
  const auto sparks = run_cli("info '" + pstream::test::data_path("sims/blender_sparks.abc") + "'");
  EXPECT_EQ(sparks.output.find("written without ids"), std::string::npos) << sparks.output;
}

}  // namespace
