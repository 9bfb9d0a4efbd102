// Encoding the FLIP fixture's [x y z scale] records at the default bounds (no ids: the particle
// codec pairs each frame's particles with the frame before's by position), one core, thread CPU
// time, and the matching alone on the same frames in the same run: BM_MatchFlipPour's time over
// BM_EncodeFlipPour's is the matching's share of the encode without ids (docs/compression.md,
// "What it does", 2). Both report particles a second.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "format/particle_common.hpp"
#include "format/particle_matching.hpp"
#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "temporary_cook.hpp"

namespace {

using namespace pstream;

// Each of a frame's positions on the codec's grid, an array an axis: the values the encoder
// quantises a source frame to, or a decoded frame's (which lie on the grid).
void to_grid(const format::CodecInfo& codec, std::span<const std::byte> records, std::uint32_t record_size,
             std::vector<std::uint32_t> (&grid)[3]) {
  for (std::size_t a = 0; a < 3; ++a) {
    const format::WordCodingEntry& e = codec.words[a];
    const double origin = double(format::particle::as_float(e.base));
    grid[a].resize(records.size() / record_size);
    for (std::size_t j = 0; j < grid[a].size(); ++j) {
      float x;
      std::memcpy(&x, records.data() + j * record_size + 4 * a, 4);
      const double t = std::nearbyint((double(x) - origin) / double(e.step));
      grid[a][j] = static_cast<std::uint32_t>(static_cast<std::int32_t>(t));
    }
  }
}

// The fixture's frames as the cook reads them ([x y z scale] records in the source's order), and
// its default cook (into a temporary file, removed again): the codec's plan, and each frame as the
// encoder pairs it, its positions in the source's order against the frame before's in the order
// the encoder wrote them (the decoder's).
struct SourceClip {
  format::CodecInfo codec;
  std::uint32_t record_size = 0;
  std::vector<std::vector<std::byte>> records;
  std::vector<std::vector<std::uint32_t>> source[3], written[3];  // per frame, per axis
  std::uint64_t cooked_bytes = 0;
  std::int64_t particles = 0, bytes = 0;

  SourceClip() {
    cook::Options o;
    o.color_from = "none";
    o.keep_velocity = false;
    o.input = PSTREAM_TEST_DATA "/sims/blender_flip_pour_small.abc";
    cook::read_frames(o, [&](const format::Metadata& m, const cook::CookedFrame& f) {
      records.emplace_back(f.records.begin(), f.records.end());
      record_size = m.record_size;
      particles += std::int64_t(f.count);
      return true;
    });
    bytes = particles * record_size;
    const bench::TemporaryCook cooked(o, "encode");
    const format::Reader reader = format::Reader::open(cooked.path());
    const format::Metadata& m = reader.metadata();
    if (m.record_size != record_size || m.frames.size() != records.size())
      throw Error("the FLIP fixture's cook is not its frames as [x y z scale]");
    codec = m.codec;
    codec.zstd_level = format::default_particle_zstd_level(codec.order, codec.lossless);  // not stored
    std::vector<std::byte> out = format::frame_buffer(m, cooked.path().string());
    std::vector<std::uint32_t> grid[3];
    for (std::size_t f = 0; f < records.size(); ++f) {
      cooked_bytes += m.frames[f].packet_size;
      to_grid(codec, records[f], record_size, grid);
      for (std::size_t a = 0; a < 3; ++a) source[a].push_back(grid[a]);
      reader.read_frame(f, out);
      to_grid(codec, std::span(out).first(m.frames[f].count * record_size), record_size, grid);
      for (std::size_t a = 0; a < 3; ++a) written[a].push_back(grid[a]);
    }
  }
  static format::particle::GridPoints points(const std::vector<std::vector<std::uint32_t>> (&grid)[3], std::size_t f) {
    return {{grid[0][f].data(), grid[1][f].data(), grid[2][f].data()}, static_cast<std::uint32_t>(grid[0][f].size())};
  }
};

SourceClip& clip() {
  static SourceClip c;
  return c;
}

// The whole clip through encode_group, a keyframe group at a time, as the cook does on one core.
void BM_EncodeFlipPour(benchmark::State& state) {
  const SourceClip& c = clip();
  std::vector<format::SourceFrame> frames;
  for (const std::vector<std::byte>& r : c.records) frames.push_back({r, {}, r.size() / c.record_size});
  const std::span<const format::SourceFrame> all(frames);
  const std::size_t group = c.codec.keyframe_interval;
  const auto encode = [&] {
    std::uint64_t packets = 0;
    for (std::size_t f = 0; f < frames.size(); f += group) {
      const std::size_t end = std::min(frames.size(), f + group);
      for (const format::EncodedFrame& e : format::encode_group(c.codec, all.subspan(f, end - f), all.first(f), f))
        packets += e.packet.size();
    }
    return packets;
  };
  // What is timed is what the cook does: the same packets.
  if (const std::uint64_t packets = encode(); packets != c.cooked_bytes) {
    state.SkipWithError(
        ("encoded " + std::to_string(packets) + " bytes where the cook wrote " + std::to_string(c.cooked_bytes))
            .c_str());
    return;
  }
  for (auto _ : state) benchmark::DoNotOptimize(encode());
  state.SetItemsProcessed(state.iterations() * c.particles);
  state.SetBytesProcessed(state.iterations() * c.bytes);
}

// Each frame after the first paired with the frame before, the pairs a keyframe group's predicted
// frames need.
void BM_MatchFlipPour(benchmark::State& state) {
  const SourceClip& c = clip();
  format::particle::PositionMatcher matcher;
  std::vector<std::int64_t> match;
  for (auto _ : state) {
    for (std::size_t f = 1; f < c.records.size(); ++f) {
      const format::particle::GridPoints previous = SourceClip::points(c.written, f - 1);
      const format::particle::GridPoints current = SourceClip::points(c.source, f);
      match.assign(current.count, -1);
      matcher.match(previous, {}, current, match);
      benchmark::DoNotOptimize(match.data());
    }
  }
  state.SetItemsProcessed(state.iterations() * c.particles);
  state.SetBytesProcessed(state.iterations() * c.bytes);
}

BENCHMARK(BM_EncodeFlipPour)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_MatchFlipPour)->Unit(benchmark::kMillisecond);

}  // namespace
