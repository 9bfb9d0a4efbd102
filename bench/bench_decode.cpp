// Decoding every frame of a default cook (the particle codec with every attribute the cook keeps:
// the sparks with ids and derived velocity, the FLIP liquid with stored velocity), one core,
// against a memcpy of the same decoded bytes in the same run. `pstream bench codec` measures the
// codec on [x y z scale] records against its peers; this is what the stream's IO worker does.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"

namespace {

using namespace pstream;

// A fixture cooked with the defaults into a temporary file, read back into memory, removed.
struct CookedClip {
  std::vector<std::byte> file;
  format::Reader reader;
  std::vector<std::vector<std::byte>> packets;
  std::vector<std::byte> out;
  std::int64_t decoded_bytes = 0;

  explicit CookedClip(const std::string& name) : reader(cook_and_read(name, file)) {
    const format::Metadata& m = reader.metadata();
    std::vector<std::byte> scratch(m.chunk_size * 2);
    for (std::uint64_t f = 0; f < m.frames.size(); ++f) {
      packets.emplace_back(m.frames[f].packet_size);
      reader.read_packet(f, packets.back(), scratch);
      decoded_bytes += std::int64_t(m.frames[f].count * m.record_size);
    }
    out.resize(m.max_count * m.record_size);
  }

  static format::Reader cook_and_read(const std::string& name, std::vector<std::byte>& file) {
    const auto path = std::filesystem::temp_directory_path() /
                      ("pstream-bench-decode-" + std::to_string(::getpid()) + "-" + name + ".pstream");
    cook::Options o;
    o.input = PSTREAM_TEST_DATA "/sims/" + name + ".abc";
    o.output = path;
    cook::cook(o);
    {
      const format::Reader r = format::Reader::open(path);
      file.resize(r.file_size());
    }
    std::FILE* f = std::fopen(path.c_str(), "rb");
    const std::size_t got = f ? std::fread(file.data(), 1, file.size(), f) : 0;
    if (f) std::fclose(f);
    std::filesystem::remove(path);
    if (got != file.size()) throw std::runtime_error("could not read back " + path.string());
    return format::Reader::from_memory(file, name);
  }
};

CookedClip& clip(int which) {
  static CookedClip sparks("blender_sparks"), flip("blender_flip_pour_small");
  return which == 0 ? sparks : flip;
}

void BM_DecodeDefaultCook(benchmark::State& state) {
  CookedClip& c = clip(static_cast<int>(state.range(0)));
  const format::Metadata& m = c.reader.metadata();
  format::FrameDecoder decoder(m, c.reader.name());
  for (auto _ : state) {
    for (std::uint64_t f = 0; f < m.frames.size(); ++f) decoder.decode(f, c.packets[f], c.out);
    benchmark::DoNotOptimize(c.out.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * c.decoded_bytes);
  state.SetLabel(state.range(0) == 0 ? "sparks (ids, derived velocity)" : "FLIP (no ids, stored velocity)");
}

void BM_MemcpyDecodedBytes(benchmark::State& state) {
  CookedClip& c = clip(static_cast<int>(state.range(0)));
  const format::Metadata& m = c.reader.metadata();
  std::vector<std::byte> src(c.out.size(), std::byte{1});
  for (auto _ : state) {
    for (std::uint64_t f = 0; f < m.frames.size(); ++f)
      std::memcpy(c.out.data(), src.data(), m.frames[f].count * m.record_size);
    benchmark::DoNotOptimize(c.out.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * c.decoded_bytes);
}

BENCHMARK(BM_MemcpyDecodedBytes)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_DecodeDefaultCook)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace
