// GpuSorter: a stable LSD radix sort of (key, value) pairs in compute shaders. No subgroup
// operations (Mesa's llvmpipe has none), so one design runs on CI and on GPUs alike.
//
// Each pass sorts by one 4-bit digit, in three dispatches:
//   count   — per block of kBlockItems pairs, how many of each digit (shared-memory atomics);
//   scan    — exclusive prefix over the counts in digit-major order (digit 0 of every block,
//             then digit 1, ...): where each block's pairs of each digit start in the output;
//   scatter — the block is ordered by digit in shared memory first, then written out, so that
//             neighbouring threads write neighbouring addresses of one digit's run (coalesced:
//             a block's 16 runs average 256 pairs). Each thread owns a contiguous run of
//             kThreadItems pairs; a prefix over the block's per-thread digit counts, in digit
//             then thread order, gives each pair its place in the block and keeps equal digits
//             in input order, so the sort is stable and equal keys keep the order of their values.
// Every global read and write walks the block with the thread index fastest (coalesced).
// 32-bit keys take 8 passes, 16-bit keys 4; both end in the first buffer pair.
#include <algorithm>
#include <initializer_list>
#include <numeric>
#include <string>

#include <epoxy/gl.h>
#include <fmt/format.h>

#include "gl_program.hpp"
#include "particlestream/render.hpp"

namespace pstream::render {
namespace {

constexpr std::uint32_t kThreads = 256, kThreadItems = 16, kBlockItems = kThreads * kThreadItems;
constexpr std::uint32_t kDigitBits = 4, kDigits = 1u << kDigitBits;

// Every kernel's first lines: the version, the work-group size and the constants above (written
// once, here), and the record head's position word (frame.hpp).
std::string glsl_header() {
  return fmt::format(
      "#version 430\nlayout(local_size_x = {0}) in;\nconst uint kThreads = {0}u, kThreadItems = {1}u, "
      "kBlockItems = {2}u, kDigits = {3}u, kPositionWord = {4}u;\n",
      kThreads, kThreadItems, kBlockItems, kDigits, kPositionOffset / 4);
}

// Shared by the three sorting kernels: the buffers and the pass's parameters.
constexpr const char* kPrelude = R"(
layout(std430, binding = 0) readonly buffer KeysIn { uint keys_in[]; };
layout(std430, binding = 1) readonly buffer ValuesIn { uint values_in[]; };
layout(std430, binding = 2) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 3) writeonly buffer ValuesOut { uint values_out[]; };
layout(std430, binding = 4) buffer Counts { uint counts[]; };  // [digit * blocks + block]
uniform uint u_count;
uniform uint u_shift;
uniform uint u_blocks;
uint digit_of(uint key) { return (key >> u_shift) & (kDigits - 1u); }
)";

constexpr const char* kCount = R"(
shared uint block_counts[kDigits];
void main() {
  uint t = gl_LocalInvocationID.x, b = gl_WorkGroupID.x;
  if (t < kDigits) block_counts[t] = 0u;
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint i = b * kBlockItems + k * kThreads + t;
    if (i < u_count) atomicAdd(block_counts[digit_of(keys_in[i])], 1u);
  }
  barrier();
  if (t < kDigits) counts[t * u_blocks + b] = block_counts[t];
}
)";

// An inclusive prefix over `partial[0..kThreads)` in place, in log2(kThreads) steps (every thread
// of the work group calls it). Shared by the scan and the scatter.
constexpr const char* kGroupPrefix = R"(
void inclusive_prefix(uint t) {
  for (uint offset = 1u; offset < kThreads; offset <<= 1u) {
    uint v = partial[t] + (t >= offset ? partial[t - offset] : 0u);
    barrier();
    partial[t] = v;
    barrier();
  }
}
)";

constexpr const char* kScan = R"(
shared uint partial[kThreads];
)";
constexpr const char* kScanMain = R"(
void main() {
  uint t = gl_LocalInvocationID.x;
  uint n = kDigits * u_blocks, per = (n + kThreads - 1u) / kThreads, begin = min(t * per, n),
       end = min(begin + per, n);
  uint sum = 0u;
  for (uint i = begin; i < end; ++i) sum += counts[i];
  partial[t] = sum;
  barrier();
  inclusive_prefix(t);
  uint running = partial[t] - sum;
  for (uint i = begin; i < end; ++i) {
    uint c = counts[i];
    counts[i] = running;
    running += c;
  }
}
)";

// 32 KB of shared memory (OpenGL's guaranteed minimum): the per-thread digit counts, then places
// (16 KB), and one block of keys, then of values (16 KB), whose first kThreads words also serve as
// the prefix's partial sums. Per-thread arrays are indexed only by loop counters (registers); a
// thread's counts live in its own column of `place`, where lanes never share a bank, because an
// array indexed by a random digit goes to per-lane local memory on GPUs and serialises the warp.
constexpr const char* kScatter = R"(
shared uint place[kDigits * kThreads];  // [digit * kThreads + thread]: counts, then where those pairs go in the block
shared uint partial[kBlockItems];       // the block's keys or values
)";
constexpr const char* kScatterMain = R"(
void main() {
  uint t = gl_LocalInvocationID.x, b = gl_WorkGroupID.x, base = b * kBlockItems;
  uint items = min(kBlockItems, u_count - base);
  // This thread's contiguous run of the block, read through shared memory so that the global
  // reads are coalesced, and the run's digit counts.
  uint key[kThreadItems], value[kThreadItems], slot[kThreadItems], dest[kThreadItems];
  for (uint d = 0u; d < kDigits; ++d) place[d * kThreads + t] = 0u;
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint j = k * kThreads + t;
    if (j < items) partial[j] = keys_in[base + j];
  }
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint j = t * kThreadItems + k;
    key[k] = j < items ? partial[j] : 0u;
    if (j < items) place[digit_of(key[k]) * kThreads + t] += 1u;
  }
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint j = k * kThreads + t;
    if (j < items) partial[j] = values_in[base + j];
  }
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) value[k] = partial[t * kThreadItems + k];
  barrier();
  // Exclusive prefix over `place` in its digit-major order: each thread sums a contiguous
  // kDigits entries, the partial sums are prefixed, then each thread writes its entries' places.
  uint sum = 0u;
  for (uint k = 0u; k < kDigits; ++k) sum += place[t * kDigits + k];
  partial[t] = sum;
  barrier();
  inclusive_prefix(t);
  uint running = partial[t] - sum;
  for (uint k = 0u; k < kDigits; ++k) {
    uint c = place[t * kDigits + k];
    place[t * kDigits + k] = running;
    running += c;
  }
  barrier();
  // The keys in the block's digit order. Afterwards the last thread's entry of each digit holds
  // where the next digit starts in the block.
  for (uint k = 0u; k < kThreadItems; ++k) {
    if (t * kThreadItems + k < items) {
      uint at = digit_of(key[k]) * kThreads + t;
      slot[k] = place[at];
      place[at] = slot[k] + 1u;
      partial[slot[k]] = key[k];
    }
  }
  barrier();
  // Each digit's output index less its start in the block, in place[0..kDigits).
  uint shift = 0u;
  if (t < kDigits) shift = counts[t * u_blocks + b] - (t == 0u ? 0u : place[(t - 1u) * kThreads + kThreads - 1u]);
  barrier();
  if (t < kDigits) place[t] = shift;
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint j = k * kThreads + t;
    if (j < items) {
      uint sorted = partial[j];
      dest[k] = place[digit_of(sorted)] + j;
      keys_out[dest[k]] = sorted;
    }
  }
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) {
    if (t * kThreadItems + k < items) partial[slot[k]] = value[k];
  }
  barrier();
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint j = k * kThreads + t;
    if (j < items) values_out[dest[k]] = partial[j];
  }
}
)";

// Depth keys for the camera: depth = dot(position, axis.xyz) + axis.w in exactly the CPU's
// operations and order (`precise`: no fused multiply-add), mapped to an order-preserving
// unsigned key (flipped for back to front), with the particle's index as the value.
constexpr const char* kDepthKeys = R"(
layout(std430, binding = 0) readonly buffer Records { uint words[]; };
layout(std430, binding = 2) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 3) writeonly buffer ValuesOut { uint values_out[]; };
uniform uint u_count;
uniform uint u_stride_words;
uniform uint u_base_words;
uniform vec4 u_axis;
uniform bool u_back_to_front;
uniform uint u_first;  // where this batch's pairs start
uniform uint u_tag;    // or-ed into the values: (batch << kMergedIndexBits) for a merged sort
void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= u_count) return;
  uint w = u_base_words + i * u_stride_words + kPositionWord;
  vec3 p = uintBitsToFloat(uvec3(words[w], words[w + 1u], words[w + 2u]));
  precise float d = ((p.x * u_axis.x + p.y * u_axis.y) + p.z * u_axis.z) + u_axis.w;
  uint u = floatBitsToUint(d);
  uint key = u ^ ((u & 0x80000000u) != 0u ? 0xFFFFFFFFu : 0x80000000u);
  keys_out[u_first + i] = u_back_to_front ? ~key : key;
  values_out[u_first + i] = u_tag | i;
}
)";

GLuint program(std::initializer_list<const char*> parts) {
  std::string source = glsl_header();
  for (const char* p : parts) source += p;
  return detail::link_compute_program(source.c_str());
}

}  // namespace

struct GpuSorter::Impl {
  std::uint32_t capacity = 0, max_blocks = 0;
  GLuint keys[2] = {0, 0}, values[2] = {0, 0}, counts = 0;
  GLuint count = 0, scan = 0, scatter = 0, depth_keys = 0;
  ~Impl() {
    glDeleteBuffers(2, keys);
    glDeleteBuffers(2, values);
    glDeleteBuffers(1, &counts);
    for (const GLuint p : {count, scan, scatter, depth_keys}) glDeleteProgram(p);
  }
};

GpuSorter::GpuSorter(std::uint32_t capacity) : impl_(std::make_unique<Impl>()) {
  if (epoxy_gl_version() < 43 && !epoxy_has_gl_extension("GL_ARB_compute_shader"))
    throw Error("GpuSorter: the OpenGL context has no compute shaders (OpenGL 4.3)");
  Impl& d = *impl_;
  d.capacity = std::max<std::uint32_t>(capacity, 1);
  d.max_blocks = (d.capacity + kBlockItems - 1) / kBlockItems;
  const GLsizeiptr bytes = GLsizeiptr(d.capacity) * 4;
  glCreateBuffers(2, d.keys);
  glCreateBuffers(2, d.values);
  glCreateBuffers(1, &d.counts);
  for (int i = 0; i < 2; ++i) {
    glNamedBufferStorage(d.keys[i], bytes, nullptr, GL_DYNAMIC_STORAGE_BIT);
    glNamedBufferStorage(d.values[i], bytes, nullptr, GL_DYNAMIC_STORAGE_BIT);
  }
  glNamedBufferStorage(d.counts, GLsizeiptr(kDigits) * d.max_blocks * 4, nullptr, GL_DYNAMIC_STORAGE_BIT);
  d.count = program({kPrelude, kCount});
  d.scan = program({kPrelude, kScan, kGroupPrefix, kScanMain});
  d.scatter = program({kPrelude, kScatter, kGroupPrefix, kScatterMain});
  d.depth_keys = program({kDepthKeys});
}

void GpuSorter::depth_keys(std::uint32_t records, std::uint64_t offset, std::uint32_t count, std::uint32_t stride,
                           const std::array<float, 4>& axis, bool back_to_front, std::uint32_t first,
                           std::uint32_t tag) {
  Impl& d = *impl_;
  if (std::uint64_t(first) + count > d.capacity)
    throw Error(fmt::format("GpuSorter: {} pairs, capacity {}", std::uint64_t(first) + count, d.capacity));
  if (stride % 4 != 0 || offset % 4 != 0) throw Error("GpuSorter: records must be 4-byte aligned");
  if (count == 0) return;
  glUseProgram(d.depth_keys);
  glUniform1ui(glGetUniformLocation(d.depth_keys, "u_count"), count);
  glUniform1ui(glGetUniformLocation(d.depth_keys, "u_stride_words"), stride / 4);
  glUniform1ui(glGetUniformLocation(d.depth_keys, "u_base_words"), std::uint32_t(offset / 4));
  glUniform4f(glGetUniformLocation(d.depth_keys, "u_axis"), axis[0], axis[1], axis[2], axis[3]);
  glUniform1i(glGetUniformLocation(d.depth_keys, "u_back_to_front"), back_to_front ? 1 : 0);
  glUniform1ui(glGetUniformLocation(d.depth_keys, "u_first"), first);
  glUniform1ui(glGetUniformLocation(d.depth_keys, "u_tag"), tag);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, records);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, d.keys[0]);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, d.values[0]);
  glDispatchCompute((count + kThreads - 1) / kThreads, 1, 1);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  glUseProgram(0);
}

std::vector<std::uint32_t> GpuSorter::order_by_depth(std::span<const std::byte> records, std::uint32_t stride,
                                                     const std::array<float, 4>& axis, bool back_to_front) {
  const auto n = static_cast<std::uint32_t>(stride ? records.size() / stride : 0);
  std::vector<std::uint32_t> order(n);
  if (n == 0) return order;
  GLuint buffer = 0;
  glCreateBuffers(1, &buffer);
  glNamedBufferStorage(buffer, GLsizeiptr(records.size()), records.data(), 0);
  depth_keys(buffer, 0, n, stride, axis, back_to_front);
  sort(n, 32);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  glGetNamedBufferSubData(impl_->values[0], 0, GLsizeiptr(n) * 4, order.data());
  glDeleteBuffers(1, &buffer);
  return order;
}

GpuSorter::~GpuSorter() = default;

std::uint32_t GpuSorter::capacity() const { return impl_->capacity; }
std::uint32_t GpuSorter::keys_buffer() const { return impl_->keys[0]; }
std::uint32_t GpuSorter::values_buffer() const { return impl_->values[0]; }

void GpuSorter::sort(std::uint32_t count, int key_bits) {
  Impl& d = *impl_;
  if (count > d.capacity) throw Error(fmt::format("GpuSorter: {} pairs, capacity {}", count, d.capacity));
  if (key_bits != 32 && key_bits != 16) throw Error(fmt::format("GpuSorter: {}-bit keys (32 or 16)", key_bits));
  if (count <= 1) return;
  const std::uint32_t blocks = (count + kBlockItems - 1) / kBlockItems;
  const auto set = [&](GLuint p, std::uint32_t shift) {
    glUseProgram(p);
    glUniform1ui(glGetUniformLocation(p, "u_count"), count);
    glUniform1ui(glGetUniformLocation(p, "u_shift"), shift);
    glUniform1ui(glGetUniformLocation(p, "u_blocks"), blocks);
  };
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 4, d.counts);
  for (int pass = 0; pass < key_bits / int(kDigitBits); ++pass) {
    const int from = pass & 1, to = from ^ 1;
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, d.keys[from]);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, d.values[from]);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, d.keys[to]);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, d.values[to]);
    const std::uint32_t shift = std::uint32_t(pass) * kDigitBits;
    set(d.count, shift);
    glDispatchCompute(blocks, 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    set(d.scan, shift);
    glDispatchCompute(1, 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    set(d.scatter, shift);
    glDispatchCompute(blocks, 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  }
  glUseProgram(0);
}

std::vector<std::uint32_t> GpuSorter::sort_indices(std::span<const std::uint32_t> keys, int key_bits) {
  Impl& d = *impl_;
  const auto n = static_cast<std::uint32_t>(keys.size());
  if (keys.size() > d.capacity) throw Error(fmt::format("GpuSorter: {} pairs, capacity {}", keys.size(), d.capacity));
  std::vector<std::uint32_t> values(n);
  std::iota(values.begin(), values.end(), 0u);
  if (n == 0) return values;
  glNamedBufferSubData(d.keys[0], 0, GLsizeiptr(n) * 4, keys.data());
  glNamedBufferSubData(d.values[0], 0, GLsizeiptr(n) * 4, values.data());
  sort(n, key_bits);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  glGetNamedBufferSubData(d.values[0], 0, GLsizeiptr(n) * 4, values.data());
  return values;
}

}  // namespace pstream::render
