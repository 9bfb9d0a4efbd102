// Decoding every frame of a cooked fixture, one core, against a memcpy of the same decoded bytes
// in the same run. Arguments 0 and 1: the default cooks (the particle codec with every attribute
// the cook keeps: the sparks with ids and derived velocity, the FLIP liquid with stored velocity),
// what the stream's IO worker does. Arguments 2 and 3: the same fixtures as [x y z scale] records,
// the records `pstream bench codec` measures the codec on against its peers.
#include <benchmark/benchmark.h>

#include <cstring>
#include <iterator>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "temporary_cook.hpp"

namespace {

using namespace pstream;

// A fixture cooked with the defaults into a temporary file (removed again): its metadata and
// every frame's packet, in memory.
struct CookedClip {
  std::string name;
  format::Metadata meta;
  std::vector<std::vector<std::byte>> packets;
  std::vector<std::byte> out;
  std::int64_t decoded_bytes = 0;

  CookedClip(std::string fixture, bool records_only) : name(std::move(fixture)) {
    cook::Options o;
    if (records_only) {  // [x y z scale], as `pstream bench codec` measures
      o.color_from = "none";
      o.keep_velocity = false;
    }
    o.input = PSTREAM_TEST_DATA "/sims/" + name + ".abc";
    const bench::TemporaryCook cooked(o, "decode-" + name);
    const format::Reader reader = format::Reader::open(cooked.path());
    meta = reader.metadata();
    std::vector<std::byte> scratch(meta.chunk_size * 2);
    for (std::uint64_t f = 0; f < meta.frames.size(); ++f) {
      packets.emplace_back(meta.frames[f].packet_size);
      reader.read_packet(f, packets.back(), scratch);
      decoded_bytes += std::int64_t(meta.frames[f].count * meta.record_size);
    }
    out.resize(meta.max_count * meta.record_size);
  }
};

// 0, 1: the default cooks of the sparks and the FLIP pour; 2, 3: the same as [x y z scale] records.
struct ClipCase {
  const char* fixture;
  bool records_only;
  const char* label;
};
constexpr ClipCase kClips[] = {{"blender_sparks", false, "sparks (ids, derived velocity)"},
                               {"blender_flip_pour_small", false, "FLIP (no ids, stored velocity)"},
                               {"blender_sparks", true, "sparks [x y z scale]"},
                               {"blender_flip_pour_small", true, "FLIP [x y z scale]"}};

// Each clip is cooked the first time a benchmark asks for it, so a filtered run cooks only its own.
CookedClip& clip(std::int64_t which) {
  static std::optional<CookedClip> clips[std::size(kClips)];
  std::optional<CookedClip>& c = clips[which];
  if (!c) c.emplace(kClips[which].fixture, kClips[which].records_only);
  return *c;
}

void BM_DecodeCookedClip(benchmark::State& state) {
  CookedClip& c = clip(state.range(0));
  const format::Metadata& m = c.meta;
  format::FrameDecoder decoder(m, c.name);
  for (auto _ : state) {
    for (std::uint64_t f = 0; f < m.frames.size(); ++f) decoder.decode(f, c.packets[f], c.out);
    benchmark::DoNotOptimize(c.out.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * c.decoded_bytes);
  state.SetLabel(std::string(kClips[state.range(0)].label) + ", " + std::string(format::particle_decoder_simd()));
}

void BM_MemcpyDecodedBytes(benchmark::State& state) {
  CookedClip& c = clip(state.range(0));
  const format::Metadata& m = c.meta;
  std::vector<std::byte> src(c.out.size(), std::byte{1});
  for (auto _ : state) {
    for (std::uint64_t f = 0; f < m.frames.size(); ++f)
      std::memcpy(c.out.data(), src.data(), m.frames[f].count * m.record_size);
    benchmark::DoNotOptimize(c.out.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * c.decoded_bytes);
}

BENCHMARK(BM_MemcpyDecodedBytes)->DenseRange(0, 3)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_DecodeCookedClip)->DenseRange(0, 3)->Unit(benchmark::kMillisecond);

}  // namespace
