// `pstream bench codec FILE`: the particle codec against general and geometry codecs on the same
// frames of [x y z scale] records, in one run: size, error, encode and decode speed, with a memcpy
// of the decoded bytes measured beside each decode. Times are the thread's CPU time (one core; a
// shared machine's other work does not count), medians of the repetitions (encodes: of as many as
// fit in a time budget).
#include <lz4.h>
#include <meshoptimizer.h>
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <numeric>

#include <draco/compression/decode.h>
#include <draco/compression/encode.h>
#include <draco/point_cloud/point_cloud_builder.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "base/names.hpp"
#include "base/output_file.hpp"
#include "commands.hpp"
#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "progress.hpp"
#include "stats.hpp"

namespace pstream::app {
namespace {

using format::Attribute;

constexpr std::uint32_t kRecord = 16;  // [x y z scale]

struct Frame {
  std::vector<std::byte> records;
  std::vector<std::uint64_t> ids;
  std::uint64_t count = 0;
};

// The names the table prints and --codec takes.
constexpr std::string_view kRaw = "raw";
constexpr std::string_view kLz4 = "lz4";
constexpr std::string_view kShuffle = "shuffle + zstd -3";
constexpr std::string_view kOurs = "particle (ours)";
constexpr std::string_view kOursLossless = "particle lossless (ours)";
constexpr std::string_view kZstd3 = "zstd -3";  // the issue's baseline
constexpr std::string_view kZstd19 = "zstd -19";
constexpr std::string_view kMeshopt = "meshopt + zstd -3";  // the peer
constexpr std::string_view kDraco = "draco";
constexpr std::string_view kCodecNames[] = {kRaw,     kLz4,   kZstd3, kZstd19,      kShuffle,
                                            kMeshopt, kDraco, kOurs,  kOursLossless};

// One codec under test: encode every frame, decode every frame in order into `out` (a frame's
// records, the frame index given).
struct Contender {
  std::string name;
  std::function<std::vector<std::vector<std::byte>>(const std::vector<Frame>&)> encode;
  std::function<void(const std::vector<std::vector<std::byte>>&, std::size_t, std::span<std::byte>)> decode;
  bool reorders = false;  // decoded frames are in another order: pair particles by position
};

// Seconds of this thread's CPU time since `t0_ms` (thread_cpu_ms()).
double cpu_seconds_since(double t0_ms) { return (thread_cpu_ms() - t0_ms) / 1e3; }

std::vector<std::byte> zstd_compress(std::span<const std::byte> in, int level) {
  std::vector<std::byte> out(ZSTD_compressBound(in.size()));
  const std::size_t n = ZSTD_compress(out.data(), out.size(), in.data(), in.size(), level);
  if (ZSTD_isError(n)) throw Error(fmt::format("zstd: {}", ZSTD_getErrorName(n)));
  out.resize(n);
  return out;
}

void zstd_decompress(ZSTD_DCtx* ctx, std::span<const std::byte> in, std::span<std::byte> out) {
  const std::size_t n = ZSTD_decompressDCtx(ctx, out.data(), out.size(), in.data(), in.size());
  if (ZSTD_isError(n) || n != out.size()) throw Error("zstd: corrupt bench data");
}

// The source's frames as [x y z scale] records, with ids when it has them (read as the cook reads
// them, so exactly what a cooked clip would hold).
std::vector<Frame> load_frames(const BenchCodecOptions& o) {
  cook::Options c;
  c.input = o.file;
  c.object = o.object;
  c.color_from = "none";
  c.frame_codec = format::FrameCodec::Records;  // the records as they are
  c.keep_velocity = false;                      // [x y z scale] (+ id)
  c.attributes = {"id"};
  std::vector<Frame> out;
  const auto take = [&](const format::Metadata& m, const cook::CookedFrame& cf) {
    const format::Attribute* id = m.find("id");
    Frame& fr = out.emplace_back();
    fr.count = cf.count;
    fr.records.resize(fr.count * kRecord);
    if (id) fr.ids.resize(fr.count);
    for (std::uint64_t i = 0; i < fr.count; ++i) {
      std::memcpy(fr.records.data() + i * kRecord, cf.records.data() + i * m.record_size, kRecord);
      if (id) std::memcpy(&fr.ids[i], cf.records.data() + i * m.record_size + id->offset, 8);
    }
    return o.frames == 0 || out.size() < o.frames;
  };
  try {
    cook::read_frames(c, take);
  } catch (const Error&) {
    if (!out.empty()) throw;  // failed on a frame, not for want of ids
    c.attributes.clear();     // no ids
    cook::read_frames(c, take);
  }
  return out;
}

// Particle i against particle i: the largest difference per word.
void compare_in_order(std::span<const std::byte> decoded, std::span<const std::byte> source, std::uint64_t n,
                      format::FrameComparison& cmp) {
  cmp.max_error.resize(std::max<std::size_t>(cmp.max_error.size(), 4), 0.0);
  cmp.max_relative_error.resize(std::max<std::size_t>(cmp.max_relative_error.size(), 4), 0.0);
  cmp.particles += n;
  for (std::uint64_t i = 0; i < n; ++i) {
    float a[4], b[4];
    std::memcpy(a, decoded.data() + i * kRecord, kRecord);
    std::memcpy(b, source.data() + i * kRecord, kRecord);
    for (std::size_t w = 0; w < 4; ++w) {
      const double e = std::abs(double(a[w]) - double(b[w]));
      cmp.max_error[w] = std::max(cmp.max_error[w], e);
      if (e > 0) cmp.max_relative_error[w] = std::max(cmp.max_relative_error[w], e / std::abs(double(b[w])));
    }
  }
}

// The grid a quantised coordinate or scale lives on, from the particle codec's plan: a uniform
// grid (positions), or the relative one (scale: the float's bits with low mantissa bits dropped).
struct Grid {
  float step = 0.0f, origin = 0.0f;
  std::uint32_t shift = 0;  // relative: the mantissa bits dropped
  bool valid() const { return step > 0 || shift > 0; }
  std::uint32_t quantize(float v) const {
    if (shift > 0) return format::relative_code(std::bit_cast<std::uint32_t>(v), shift);
    return static_cast<std::uint32_t>(std::max(0.0, std::nearbyint((double(v) - origin) / step)));
  }
  float dequantize(std::uint32_t q) const {
    if (shift > 0) return std::bit_cast<float>(format::relative_decode(q, shift));
    return static_cast<float>(q) * step + origin;
  }
};

Grid grid_of(const format::CodecInfo& info, std::size_t word) {
  const format::WordCodingEntry& e = info.words[word];
  if (e.coding == format::WordCoding::Quantized) return {e.step, std::bit_cast<float>(e.base), 0};
  // The coarsest relative grid that keeps the bound (the particle codec's own is one bit finer,
  // for its codes chosen in the loop): what a codec without a predictor of its own would use.
  if (e.coding == format::WordCoding::Relative) return {0.0f, 0.0f, format::relative_shift_for(e.error)};
  if (e.coding == format::WordCoding::Constant) return {1.0f, std::bit_cast<float>(e.base), 0};
  return {};
}

std::vector<Contender> contenders(const format::CodecInfo& lossy, const format::CodecInfo& lossless,
                                  const std::vector<Attribute>& layout, std::uint64_t max_count) {
  std::vector<Contender> all;
  all.push_back({std::string(kRaw),
                 [](const std::vector<Frame>& frames) {
                   std::vector<std::vector<std::byte>> out;
                   for (const Frame& f : frames) out.push_back(f.records);
                   return out;
                 },
                 [](const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                   if (!enc[f].empty()) std::memcpy(out.data(), enc[f].data(), enc[f].size());
                 }});
  all.push_back({std::string(kLz4),
                 [](const std::vector<Frame>& frames) {
                   std::vector<std::vector<std::byte>> out;
                   for (const Frame& f : frames) {
                     std::vector<std::byte> z(std::size_t(LZ4_compressBound(int(f.records.size()))));
                     z.resize(std::size_t(LZ4_compress_default(reinterpret_cast<const char*>(f.records.data()),
                                                               reinterpret_cast<char*>(z.data()), int(f.records.size()),
                                                               int(z.size()))));
                     out.push_back(std::move(z));
                   }
                   return out;
                 },
                 [](const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                   LZ4_decompress_safe(reinterpret_cast<const char*>(enc[f].data()),
                                       reinterpret_cast<char*>(out.data()), int(enc[f].size()), int(out.size()));
                 }});
  for (const auto& [name, level] : {std::pair{kZstd3, 3}, std::pair{kZstd19, 19}}) {
    all.push_back({std::string(name),
                   [level = level](const std::vector<Frame>& frames) {
                     std::vector<std::vector<std::byte>> out;
                     for (const Frame& f : frames) out.push_back(zstd_compress(f.records, level));
                     return out;
                   },
                   [ctx = std::shared_ptr<ZSTD_DCtx>(ZSTD_createDCtx(), ZSTD_freeDCtx)](
                       const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                     zstd_decompress(ctx.get(), enc[f], out);
                   }});
  }
  // Byte shuffle: the records' bytes by position in the record, then zstd.
  auto shuffled = std::make_shared<std::vector<std::byte>>(max_count * kRecord);
  all.push_back({std::string(kShuffle),
                 [](const std::vector<Frame>& frames) {
                   std::vector<std::vector<std::byte>> out;
                   std::vector<std::byte> planes;
                   for (const Frame& f : frames) {
                     planes.resize(f.records.size());
                     for (std::uint64_t i = 0; i < f.count; ++i)
                       for (std::uint32_t b = 0; b < kRecord; ++b) planes[b * f.count + i] = f.records[i * kRecord + b];
                     out.push_back(zstd_compress(planes, 3));
                   }
                   return out;
                 },
                 [shuffled, ctx = std::shared_ptr<ZSTD_DCtx>(ZSTD_createDCtx(), ZSTD_freeDCtx)](
                     const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                   const std::size_t n = out.size() / kRecord;
                   zstd_decompress(ctx.get(), enc[f], std::span(*shuffled).first(out.size()));
                   for (std::uint32_t b = 0; b < kRecord; ++b) {
                     const std::byte* plane = shuffled->data() + b * n;
                     for (std::size_t i = 0; i < n; ++i) out[i * kRecord + b] = plane[i];
                   }
                 }});
  // meshoptimizer's vertex codec on the same grids (16-bit when the grid fits), then zstd.
  const Grid gx = grid_of(lossy, 0), gy = grid_of(lossy, 1), gz = grid_of(lossy, 2), gs = grid_of(lossy, 3);
  auto vertices = std::make_shared<std::vector<std::uint16_t>>(max_count * 4);
  auto packed = std::make_shared<std::vector<std::byte>>(meshopt_encodeVertexBufferBound(max_count, 8));
  all.push_back({std::string(kMeshopt),
                 [=](const std::vector<Frame>& frames) {
                   std::vector<std::vector<std::byte>> out;
                   std::vector<std::uint16_t> v;
                   std::vector<std::byte> buf;
                   for (const Frame& f : frames) {
                     v.resize(f.count * 4);
                     for (std::uint64_t i = 0; i < f.count; ++i) {
                       float r[4];
                       std::memcpy(r, f.records.data() + i * kRecord, kRecord);
                       v[i * 4] = std::uint16_t(gx.quantize(r[0]));
                       v[i * 4 + 1] = std::uint16_t(gy.quantize(r[1]));
                       v[i * 4 + 2] = std::uint16_t(gz.quantize(r[2]));
                       v[i * 4 + 3] = gs.valid() ? std::uint16_t(gs.quantize(r[3])) : 0;
                     }
                     buf.resize(meshopt_encodeVertexBufferBound(f.count, 8));
                     buf.resize(meshopt_encodeVertexBuffer(reinterpret_cast<unsigned char*>(buf.data()), buf.size(),
                                                           v.data(), f.count, 8));
                     out.push_back(zstd_compress(buf, 3));
                   }
                   return out;
                 },
                 [=, ctx = std::shared_ptr<ZSTD_DCtx>(ZSTD_createDCtx(), ZSTD_freeDCtx)](
                     const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                   const std::size_t n = out.size() / kRecord;
                   const std::size_t size = ZSTD_getFrameContentSize(enc[f].data(), enc[f].size());
                   zstd_decompress(ctx.get(), enc[f], std::span(*packed).first(size));
                   meshopt_decodeVertexBuffer(vertices->data(), n, 8,
                                              reinterpret_cast<const unsigned char*>(packed->data()), size);
                   for (std::size_t i = 0; i < n; ++i) {
                     const std::uint16_t* q = vertices->data() + i * 4;
                     const float r[4] = {gx.dequantize(q[0]), gy.dequantize(q[1]), gz.dequantize(q[2]),
                                         gs.valid() ? gs.dequantize(q[3]) : gs.origin};
                     std::memcpy(out.data() + i * kRecord, r, kRecord);
                   }
                 }});
  // Draco's point-cloud codec, with quantisation bits that keep the same bound.
  const double bound = lossy.error;
  const double scale_bound = lossy.words[3].coding == format::WordCoding::Relative ? lossy.words[3].error : 0.0;
  all.push_back({std::string(kDraco),
                 [bound, scale_bound](const std::vector<Frame>& frames) {
                   std::vector<std::vector<std::byte>> out;
                   for (const Frame& f : frames) {
                     std::vector<float> xyz(f.count * 3), s(f.count);
                     float lo = INFINITY, hi = -INFINITY, s_lo = INFINITY, s_hi = -INFINITY;
                     for (std::uint64_t i = 0; i < f.count; ++i) {
                       float r[4];
                       std::memcpy(r, f.records.data() + i * kRecord, kRecord);
                       std::copy_n(r, 3, &xyz[i * 3]);
                       s[i] = r[3];
                       for (int c = 0; c < 3; ++c) lo = std::min(lo, r[c]), hi = std::max(hi, r[c]);
                       s_lo = std::min(s_lo, std::abs(r[3])), s_hi = std::max(s_hi, std::abs(r[3]));
                     }
                     draco::PointCloudBuilder b;
                     b.Start(static_cast<draco::PointIndex::ValueType>(f.count));
                     const int pos = b.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
                     const int sc = b.AddAttribute(draco::GeometryAttribute::GENERIC, 1, draco::DT_FLOAT32);
                     b.SetAttributeValuesForAllPoints(pos, xyz.data(), 12);
                     b.SetAttributeValuesForAllPoints(sc, s.data(), 4);
                     std::unique_ptr<draco::PointCloud> pc = b.Finalize(false);
                     draco::Encoder enc;
                     // Draco quantises over the largest extent with 2^bits - 1 steps: half a step
                     // within the bound.
                     const double range = f.count ? std::max(double(hi - lo), 1e-9) : 1.0;
                     const int bits = std::clamp(int(std::ceil(std::log2(range / (2.0 * bound) + 1.0))), 1, 30);
                     enc.SetAttributeQuantization(draco::GeometryAttribute::POSITION, bits);
                     // Scale within its relative bound on a uniform grid: half a step within the
                     // bound of the smallest scale.
                     const double s_step = 2.0 * scale_bound * std::max(double(s_lo), 1e-9);
                     const int s_bits =
                         scale_bound > 0 && f.count
                             ? std::clamp(int(std::ceil(std::log2(std::max(double(s_hi - s_lo), 1e-9) / s_step + 1.0))),
                                          1, 30)
                             : bits;
                     enc.SetAttributeQuantization(draco::GeometryAttribute::GENERIC, s_bits);
                     enc.SetSpeedOptions(5, 5);
                     draco::EncoderBuffer buffer;
                     if (!enc.EncodePointCloudToBuffer(*pc, &buffer).ok()) throw Error("draco failed to encode");
                     const auto* d = reinterpret_cast<const std::byte*>(buffer.data());
                     out.emplace_back(d, d + buffer.size());
                   }
                   return out;
                 },
                 [](const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                   draco::DecoderBuffer buffer;
                   buffer.Init(reinterpret_cast<const char*>(enc[f].data()), enc[f].size());
                   draco::Decoder dec;
                   auto pc = dec.DecodePointCloudFromBuffer(&buffer);
                   if (!pc.ok()) throw Error("draco failed to decode");
                   const draco::PointAttribute* pos = pc.value()->GetNamedAttribute(draco::GeometryAttribute::POSITION);
                   const draco::PointAttribute* sc = pc.value()->GetNamedAttribute(draco::GeometryAttribute::GENERIC);
                   const std::size_t n = out.size() / kRecord;
                   for (std::size_t i = 0; i < n; ++i) {
                     float r[4] = {0, 0, 0, 0};
                     const draco::PointIndex p(static_cast<std::uint32_t>(i));
                     pos->GetMappedValue(p, r);
                     sc->GetMappedValue(p, r + 3);
                     std::memcpy(out.data() + i * kRecord, r, kRecord);
                   }
                 },
                 true});
  // Ours: keyframe groups encoded in order, decoded in order by one FrameDecoder.
  for (const format::CodecInfo* info : {&lossy, &lossless}) {
    auto meta = std::make_shared<format::Metadata>();
    meta->layout = layout;
    meta->record_size = kRecord;
    meta->codec = *info;
    meta->max_count = max_count;
    auto decoder = std::make_shared<std::unique_ptr<format::FrameDecoder>>();
    all.push_back({std::string(info->lossless ? kOursLossless : kOurs),
                   [=](const std::vector<Frame>& frames) {
                     std::vector<std::vector<std::byte>> out;
                     meta->frames.clear();
                     const std::uint32_t K = info->keyframe_interval;
                     for (std::size_t g = 0; g < frames.size(); g += K) {
                       std::vector<format::SourceFrame> views;
                       for (std::size_t f = g; f < std::min(frames.size(), g + K); ++f)
                         views.push_back({frames[f].records, frames[f].ids, frames[f].count});
                       std::vector<format::SourceFrame> before;
                       for (std::size_t f = g - std::min<std::size_t>(g, 2); f < g; ++f)
                         before.push_back({frames[f].records, frames[f].ids, frames[f].count});
                       for (auto& e : format::encode_group(*info, views, before, g)) {
                         format::FrameEntry entry;
                         entry.count = e.count;
                         entry.keyframe = e.keyframe;
                         entry.packet_size = e.packet.size();
                         meta->frames.push_back(entry);
                         out.push_back(std::move(e.packet));
                       }
                     }
                     *decoder = std::make_unique<format::FrameDecoder>(*meta, "bench");
                     return out;
                   },
                   [=](const std::vector<std::vector<std::byte>>& enc, std::size_t f, std::span<std::byte> out) {
                     (*decoder)->decode(f, enc[f], out);
                   },
                   !info->lossless});
  }
  return all;
}

// Bytes per particle against decode speed, both on log scales, one labelled point per codec.
std::string svg_scatter(const nlohmann::ordered_json& results, const std::string& title) {
  const double W = 760, H = 440, L = 70, R = 30, T = 40, B = 50;
  double xmin = 1e300, xmax = 0, ymin = 1e300, ymax = 0;
  // Speeds clamped to 1 MB/s .. 10 TB/s: a decode too quick for the clock to see is infinitely fast.
  const auto speed = [](const nlohmann::ordered_json& r) {
    const double v = r["decode_gb_s"].get<double>();
    return std::isfinite(v) ? std::clamp(v, 1e-3, 1e4) : 1e4;
  };
  for (const auto& r : results) {
    xmin = std::min(xmin, speed(r));
    xmax = std::max(xmax, speed(r));
    ymin = std::min(ymin, r["bytes_per_particle"].get<double>());
    ymax = std::max(ymax, r["bytes_per_particle"].get<double>());
  }
  // Both axes logarithmic: the codecs' speeds span 0.1 to tens of GB/s, and on a linear axis
  // everything but raw and lz4 shared its first tenth.
  const double lx0 = std::floor(std::log10(xmin)), lx1 = std::max(lx0 + 1, std::ceil(std::log10(xmax)));
  const double ly0 = std::floor(std::log10(ymin) * 2) / 2, ly1 = std::ceil(std::log10(ymax) * 2) / 2;
  const auto px = [&](double x) { return L + (std::log10(x) - lx0) / (lx1 - lx0) * (W - L - R); };
  const auto py = [&](double y) { return H - B - (std::log10(y) - ly0) / (ly1 - ly0) * (H - T - B); };
  std::string s = fmt::format(
      R"(<svg xmlns="http://www.w3.org/2000/svg" width="{}" height="{}" font-family="sans-serif" font-size="12">)", W,
      H);
  s += fmt::format(R"(<rect width="100%" height="100%" fill="white"/><text x="{}" y="22" font-size="15">{}</text>)", L,
                   title);
  for (int e = int(lx0); e <= int(lx1); ++e) {
    for (const double m : {1.0, 2.0, 5.0}) {
      const double x = std::pow(10.0, e) * m;
      if (std::log10(x) > lx1 + 1e-9) break;
      s += fmt::format(
          R"(<line x1="{0:.1f}" y1="{1}" x2="{0:.1f}" y2="{2}" stroke="#ddd"/><text x="{0:.1f}" y="{3}" text-anchor="middle">{4:g}</text>)",
          px(x), T, H - B, H - B + 18, x);
    }
  }
  for (const double y : {0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0}) {
    if (std::log10(y) < ly0 - 1e-9 || std::log10(y) > ly1 + 1e-9) continue;
    s += fmt::format(
        R"(<line x1="{0}" y1="{1}" x2="{2}" y2="{1}" stroke="#ddd"/><text x="{3}" y="{4}" text-anchor="end">{5:g}</text>)",
        L, py(y), W - R, L - 6, py(y) + 4, y);
  }
  s += fmt::format(
      R"(<text x="{}" y="{}" text-anchor="middle">decode GB/s of records, one core, log scale (right is faster)</text>)",
      (L + W - R) / 2, H - 12);
  s += fmt::format(
      R"svg(<text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">bytes per particle per frame (down is smaller)</text>)svg",
      (T + H - B) / 2, (T + H - B) / 2);
  // Points first, then each label at the first of a few places beside its point that overlaps no
  // point (nor the room around it) and no label placed before it (boxes estimated at 7 px a
  // character, 13 px high), with a line to its point when it is not at the first place.
  struct Box {
    double x0, y0, x1, y1;
    bool hits(const Box& o) const { return x0 < o.x1 && o.x0 < x1 && y0 < o.y1 && o.y0 < y1; }
  };
  std::vector<Box> taken;
  std::vector<std::pair<double, double>> at;
  for (const auto& r : results) {
    const std::string name = r["codec"];
    const bool ours = name.find("ours") != std::string::npos;
    const double x = px(speed(r)), y = py(r["bytes_per_particle"].get<double>());
    s += fmt::format(R"(<circle cx="{:.1f}" cy="{:.1f}" r="{}" fill="{}"/>)", x, y, ours ? 6 : 4,
                     ours ? "#d62728" : "#1f77b4");
    taken.push_back({x - 9, y - 9, x + 9, y + 9});  // a point with room around it
    at.emplace_back(x, y);
  }
  for (std::size_t i = 0; i < results.size(); ++i) {
    const std::string name = results[i]["codec"];
    const auto [x, y] = at[i];
    const double w = 7.0 * double(name.size());
    constexpr double kDy[] = {-6, 16, -22, 32, -38, 48, -54};
    Box box{};
    double tx = 0, ty = 0;
    bool placed = false;
    for (const bool right : {true, false}) {
      for (const double dy : kDy) {
        tx = right ? x + 9 : x - 9 - w;
        ty = y + dy;
        box = {tx, ty - 11, tx + w, ty + 2};
        if (box.x0 < L || box.x1 > W || box.y0 < T - 10 || box.y1 > H - B) continue;
        if (std::none_of(taken.begin(), taken.end(), [&](const Box& o) { return box.hits(o); })) {
          placed = true;
          break;
        }
      }
      if (placed) break;
    }
    if (!placed) {  // nowhere free: beside the point, as before
      tx = x + 9;
      ty = y - 6;
      box = {tx, ty - 11, tx + w, ty + 2};
    }
    if (tx < x || ty != y - 6) {  // moved from beside its point: a line to it
      s += fmt::format(R"(<line x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="#999"/>)", x, y,
                       tx < x ? tx + w : tx, ty - 4);
    }
    s += fmt::format(R"(<text x="{:.1f}" y="{:.1f}">{}</text>)", tx, ty, name);
    taken.push_back(box);
  }
  return s + "</svg>\n";
}

}  // namespace

int bench_codec(const BenchCodecOptions& o) {
  // The codecs' names and the bounds first, so that a mistyped one fails before the frames load.
  for (const std::string& name : o.codecs) {
    if (std::find(std::begin(kCodecNames), std::end(kCodecNames), name) != std::end(kCodecNames)) continue;
    std::string names;
    for (const std::string_view n : kCodecNames) names += fmt::format("{}'{}'", names.empty() ? "" : ", ", n);
    throw Error(fmt::format("--codec '{}': expected one of {}{}", name, names, did_you_mean(name, kCodecNames)));
  }
  cook::Options bounds;
  cook::set_error_bound(bounds, o.error, "--error");
  cook::set_scale_error(bounds, o.scale_error, "--scale-error");
  format::ParticleCodecOptions po = bounds.particle;
  const std::string bound_text =
      po.error_relative ? fmt::format("{:g} of the diagonal", po.error) : std::string("in scene units");
  const std::vector<Frame> frames = load_frames(o);
  std::uint64_t particles = 0, max_count = 0;
  for (const Frame& f : frames) {
    particles += f.count;
    max_count = std::max(max_count, f.count);
  }
  if (particles == 0) throw Error(fmt::format("{}: no particles to compress", o.file));
  const std::vector<Attribute> layout = format::default_layout();
  format::ClipStats stats(layout);
  for (const Frame& f : frames) stats.add(f.records, f.count);
  if (o.zstd_level) po.zstd_level = o.zstd_level;
  const bool ids = !frames.empty() && !frames.front().ids.empty();
  const format::CodecInfo lossy = format::plan_particle_codec(layout, stats, 24.0, ids, po);
  po.lossless = true;
  po.zstd_level = o.zstd_level;  // 0: the lossless mode's own default
  const format::CodecInfo lossless = format::plan_particle_codec(layout, stats, 24.0, ids, po);

  const double raw_bytes = double(particles) * kRecord;
  std::vector<std::byte> out(max_count * kRecord), source(out.size());
  nlohmann::ordered_json results = nlohmann::ordered_json::array();
  ProgressBar bar("bench codec", !o.json);
  auto all = contenders(lossy, lossless, layout, max_count);
  if (!o.codecs.empty()) {
    std::erase_if(
        all, [&](const Contender& c) { return std::find(o.codecs.begin(), o.codecs.end(), c.name) == o.codecs.end(); });
  }
  // Every codec encodes first, and each keeps its output, so that the decodes can be paired: each
  // repetition decodes every frame with every codec, one codec after another, then memcpys the
  // same decoded bytes. A shared machine's drift then slows all codecs of a repetition alike, and
  // the ratios between codecs are medians of ratios within repetitions. Each codec decodes the
  // clip twice in a row, and both passes are timed:
  // - the second is the one reported (warm: the codec's input, tables and state in cache, as
  //   lzbench and Google Benchmark time a decoder), so a codec's figure does not depend on which
  //   others run in the same table;
  // - the first follows the other codecs' work, which left little of its data in cache (JSON
  //   `decode_first_pass_gb_s`). Each repetition starts one codec further along, so every codec's
  //   first pass follows each of the others in turn.
  const std::size_t steps = 2 * all.size() + std::size_t(o.repetitions);
  std::size_t done = 0;
  struct Encoded {
    std::vector<std::vector<std::byte>> packets;
    std::vector<double> encode_s;  // one a run
    std::uint64_t bytes = 0;
  };
  // Each codec encodes up to --repetitions times, and stops sooner once its runs have taken
  // kEncodeBudget seconds (at least once): a fast encode is timed as a median of several, a slow
  // one (zstd -19 or Draco on a large cache) once. Every run gives the same packets.
  constexpr double kEncodeBudget = 2.0;
  std::vector<Encoded> encoded(all.size());
  for (std::size_t i = 0; i < all.size(); ++i) {
    double spent = 0;
    do {
      const double t0 = thread_cpu_ms();
      encoded[i].packets = all[i].encode(frames);
      encoded[i].encode_s.push_back(cpu_seconds_since(t0));
      spent += encoded[i].encode_s.back();
    } while (int(encoded[i].encode_s.size()) < o.repetitions && spent < kEncodeBudget);
    for (const auto& e : encoded[i].packets) encoded[i].bytes += e.size();
    bar.update(++done, steps, "encoded with " + all[i].name);
  }
  std::vector<std::vector<double>> decode_s(all.size()), first_s(all.size());
  std::vector<double> copy_s;
  const auto decode_pass = [&](std::size_t i) {
    const double t = thread_cpu_ms();
    for (std::size_t f = 0; f < frames.size(); ++f)
      all[i].decode(encoded[i].packets, f, std::span(out).first(frames[f].count * kRecord));
    return cpu_seconds_since(t);
  };
  const auto copy_pass = [&] {
    const double t = thread_cpu_ms();
    for (const Frame& f : frames) {
      if (f.count) std::memcpy(source.data(), f.records.data(), f.records.size());
    }
    return cpu_seconds_since(t);
  };
  for (int rep = 0; rep < o.repetitions; ++rep) {
    for (std::size_t k = 0; k < all.size(); ++k) {
      const std::size_t i = (k + std::size_t(rep)) % all.size();
      first_s[i].push_back(decode_pass(i));
      decode_s[i].push_back(decode_pass(i));
    }
    copy_pass();
    copy_s.push_back(copy_pass());
    bar.update(++done, steps, fmt::format("decode repetition {} of {}", rep + 1, o.repetitions));
  }
  const double m = median(copy_s);
  for (std::size_t i = 0; i < all.size(); ++i) {
    const Contender& c = all[i];
    // The error, frame by frame: in-order codecs particle by particle; ours orders a cache with
    // ids by id (the source sorted so too), and pairs by nearest position only without ids.
    format::FrameComparison cmp;
    std::vector<std::byte> sorted;
    for (std::size_t f = 0; f < frames.size(); ++f) {
      c.decode(encoded[i].packets, f, std::span(out).first(frames[f].count * kRecord));
      const Frame& fr = frames[f];
      std::span<const std::byte> source = fr.records;
      if (c.reorders && ids) {
        std::vector<std::uint64_t> order(fr.count);
        std::iota(order.begin(), order.end(), std::uint64_t{0});
        std::stable_sort(order.begin(), order.end(), [&](auto a, auto b) { return fr.ids[a] < fr.ids[b]; });
        sorted.resize(fr.records.size());
        for (std::uint64_t i = 0; i < fr.count; ++i)
          std::memcpy(sorted.data() + i * kRecord, fr.records.data() + order[i] * kRecord, kRecord);
        source = sorted;
      }
      if (c.reorders && (!ids || c.name == kDraco)) {
        cmp.add(layout, out, fr.count, fr.records, fr.count, &lossy);  // nearest, within the bound's cells
      } else {
        compare_in_order(out, source, fr.count, cmp);
      }
    }
    const double position_error = std::max({cmp.max_error[0], cmp.max_error[1], cmp.max_error[2]});
    const double d = median(decode_s[i]);
    results.push_back({{"codec", c.name},
                       {"bytes_per_particle", double(encoded[i].bytes) / double(particles)},
                       {"ratio", raw_bytes / double(encoded[i].bytes)},
                       {"max_error_position", position_error},
                       {"max_error_scale", cmp.max_error[3]},
                       {"max_relative_error_scale", cmp.max_relative_error[3]},
                       {"unmatched", cmp.unmatched},
                       {"encode_mb_s", raw_bytes / median(encoded[i].encode_s) / 1e6},
                       {"encode_runs", encoded[i].encode_s.size()},
                       {"decode_gb_s", raw_bytes / d / 1e9},
                       {"decode_first_pass_gb_s", raw_bytes / median(first_s[i]) / 1e9},
                       {"memcpy_gb_s", raw_bytes / m / 1e9},
                       {"decode_vs_memcpy", d / m}});
    bar.update(++done, steps, "checked " + c.name);
  }
  // Ours against zstd -3 on the raw records (the issue's baseline) and against meshoptimizer +
  // zstd (the peer): the median over repetitions of the other's decode time over ours, so a
  // value above 1 means ours is faster.
  const auto faster_than = [&](std::string_view other, const std::vector<std::vector<double>>& s) {
    std::size_t us = all.size(), them = all.size();
    for (std::size_t i = 0; i < all.size(); ++i) {
      if (all[i].name == kOurs) us = i;
      if (all[i].name == other) them = i;
    }
    if (us == all.size() || them == all.size()) return 0.0;
    std::vector<double> r;
    for (int rep = 0; rep < o.repetitions; ++rep) r.push_back(s[them][rep] / s[us][rep]);
    return median(r);
  };
  const double vs_zstd = faster_than(kZstd3, decode_s), vs_meshopt = faster_than(kMeshopt, decode_s);
  const double first_vs_zstd = faster_than(kZstd3, first_s), first_vs_meshopt = faster_than(kMeshopt, first_s);
  nlohmann::ordered_json report{{"file", std::filesystem::path(o.file).filename().string()},
                                {"frames", frames.size()},
                                {"particles", particles},
                                {"ids", ids},
                                {"error_bound", lossy.error},
                                {"error_bound_spec", o.error},
                                {"scale_error", po.scale_error},
                                {"keyframe_interval", lossy.keyframe_interval},
                                {"repetitions", o.repetitions},
                                {"clock", "thread CPU time"},
                                {"ours_decoder_simd", std::string(format::particle_decoder_simd())},
                                {"ours_decode_vs_zstd", vs_zstd},
                                {"ours_decode_vs_meshopt", vs_meshopt},
                                {"ours_first_pass_vs_zstd", first_vs_zstd},
                                {"ours_first_pass_vs_meshopt", first_vs_meshopt},
                                {"codecs", results}};
  if (!o.svg.empty()) {
    write_file(o.svg, svg_scatter(results, fmt::format("{}: {} frames, error bound {}",
                                                       std::filesystem::path(o.file).filename().string(), frames.size(),
                                                       bound_text)));
  }
  if (o.json) {
    fmt::print("{}\n", report.dump(1));
    return 0;
  }
  fmt::print(
      "{}: {} frames, {} particles ({} ids), [x y z scale] records; error bound {:.3g} ({}), scale within "
      "{:g} % of its own, keyframe every {}; our decoder runs with {}\n\n",
      o.file, frames.size(), particles, ids ? "with" : "without", lossy.error, bound_text, 100.0 * po.scale_error,
      lossy.keyframe_interval, format::particle_decoder_simd());
  fmt::print("{:<26} {:>9} {:>7} {:>11} {:>11} {:>9} {:>9} {:>9} {:>9}\n", "codec", "B/p/frame", "ratio", "max err xyz",
             "max err s", "enc MB/s", "dec GB/s", "/memcpy", "1st pass");
  for (const auto& r : results) {
    fmt::print("{:<26} {:>9.3f} {:>7.2f} {:>11.3g} {:>11.3g} {:>9.1f} {:>9.2f} {:>9.2f} {:>9.2f}\n",
               r["codec"].get<std::string>(), r["bytes_per_particle"].get<double>(), r["ratio"].get<double>(),
               r["max_error_position"].get<double>(), r["max_error_scale"].get<double>(),
               r["encode_mb_s"].get<double>(), r["decode_gb_s"].get<double>(), r["decode_vs_memcpy"].get<double>(),
               r["decode_first_pass_gb_s"].get<double>());
  }
  fmt::print(
      "\n(dec GB/s: each codec's second pass over the clip in a row; 1st pass: its first, after the other "
      "codecs' work)\n");
  // Each ratio only when both codecs ran (--codec may leave either out).
  if (vs_zstd > 0) {
    fmt::print("\nparticle (ours) decodes {:.2f}x as fast as zstd -3 on the raw records", vs_zstd);
    if (vs_meshopt > 0) fmt::print(", {:.2f}x as fast as meshopt + zstd -3", vs_meshopt);
    fmt::print(" (one core, thread CPU time, medians of {} paired repetitions; first passes {:.2f}x", o.repetitions,
               first_vs_zstd);
    if (vs_meshopt > 0) fmt::print(" and {:.2f}x", first_vs_meshopt);
    fmt::print(")\n");
  } else if (vs_meshopt > 0) {
    fmt::print(
        "\nparticle (ours) decodes {:.2f}x as fast as meshopt + zstd -3 (one core, thread CPU time, medians of "
        "{} paired repetitions; first passes {:.2f}x)\n",
        vs_meshopt, o.repetitions, first_vs_meshopt);
  }
  return 0;
}

}  // namespace pstream::app
