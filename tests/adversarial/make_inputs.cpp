// Writes the adversarial input tree that tests/adversarial/run.sh feeds to every command: files
// that claim huge counts, hold impossible times, are cut short, corrupt or empty. The special
// files (a FIFO, a directory where a file is expected) are made by the script.
//   make_inputs DATA_DIR OUT_DIR
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "hostile_inputs.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"

namespace {

namespace fs = std::filesystem;
using namespace pstream;

using test::ply_header;
using test::write_archive_with_start;
std::string read(const fs::path& p) { return test::read_file(p); }
void write(const fs::path& p, const std::string& bytes) { test::write_file(p, bytes); }

void clip_with_times(const fs::path& path, std::vector<double> times) {
  format::Metadata meta;
  meta.fps = 24;
  meta.chunk_size = format::kMinChunkSize;
  meta.layout = format::default_layout();
  format::Writer writer(path, meta);
  std::vector<float> records;
  for (double t : times) {
    writer.append_frame(1, t, {0, 0, 0, 1, 1, 1});
    records.insert(records.end(), {0.0f, 0.0f, 0.0f, 0.1f});
  }
  const auto raw = std::as_bytes(std::span(records));
  writer.append_chunk(raw, format::Codec::Raw, 0, format::checksum(raw));
  writer.commit();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: make_inputs DATA_DIR OUT_DIR\n");
    return 2;
  }
  const fs::path data = argv[1], out = argv[2];
  fs::create_directories(out);
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();

  // Counts.
  write(out / "overflow.0001.ply", ply_header("ascii", "6148914691236517206") + "1 2 3\n");
  write(out / "claims.0001.ply", ply_header("binary_little_endian", "300000000"));
  write(out / "claims_ascii.0001.ply", ply_header("ascii", "300000000", 4) + "1 2 3 4\n");
  write(out / "lots.0001.ply", ply_header("ascii", "lots") + "1 2 3\n");
  write(out / "fewer.0001.ply", ply_header("ascii", "1") + "1 2 3\n4 5 6\n");
  write(out / "negative.0001.ply", ply_header("ascii", "-5") + "1 2 3\n");
  write(out / "nan_values.0001.ply", ply_header("ascii", "2") + "nan 1 2\ninf -inf 1e999\n");
  // Times.
  write_archive_with_start(out / "nan_time.abc", nan);
  write_archive_with_start(out / "inf_time.abc", inf);
  write_archive_with_start(out / "huge_time.abc", 1e300);
  clip_with_times(out / "inf_times.pstream", {0.0, inf, 2.0});
  clip_with_times(out / "backwards_times.pstream", {0.0, 1.0, 0.5});
  clip_with_times(out / "negative_times.pstream", {-1e308, -1.0});
  // Sizes: cut short, corrupt, empty.
  const std::string abc = read(data / "alembic/points_varying.abc");
  write(out / "truncated.abc", abc.substr(0, abc.size() / 2));
  write(out / "empty.abc", "");
  write(out / "empty.pstream", "");
  cook::Options o;
  o.input = data / "alembic/points_varying.abc";
  o.chunk_size = format::kMinChunkSize;
  o.attributes = {"velocity", "id"};
  o.output = out / "good.pstream";
  cook::cook(o);
  o.output = out / "good_particle.pstream";
  o.frame_codec = format::FrameCodec::Particle;
  cook::cook(o);
  const std::string clip = read(out / "good_particle.pstream");
  write(out / "truncated.pstream", clip.substr(0, clip.size() * 2 / 3));
  std::string corrupt = clip;
  for (std::size_t i = 300; i < corrupt.size() && i < 400; ++i) corrupt[i] = static_cast<char>(corrupt[i] ^ 0x55);
  write(out / "corrupt.pstream", corrupt);
  std::string tables = read(out / "good.pstream");
  for (std::size_t i = tables.size() - 64; i < tables.size(); ++i) tables[i] = '\xff';
  write(out / "corrupt_tables.pstream", tables);
  fs::copy_file(data / "alembic/points_hdf5_backend.abc", out / "hdf5.abc", fs::copy_options::overwrite_existing);
  fs::copy_file(data / "alembic/points_constant.abc", out / "good.abc", fs::copy_options::overwrite_existing);
  return 0;
}
