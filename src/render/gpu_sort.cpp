// GpuSorter: a stable LSD radix sort of (key, value) pairs in compute shaders. No subgroup
// operations (Mesa's llvmpipe has none), so one design runs on CI and on GPUs alike.
//
// Each pass sorts by one 4-bit digit, in three dispatches:
//   count   — per block of kBlockItems pairs, how many of each digit (shared-memory atomics);
//   scan    — exclusive prefix over the counts in digit-major order (digit 0 of every block,
//             then digit 1, ...): where each block's pairs of each digit start in the output;
//   scatter — each thread owns a contiguous run of kThreadItems pairs; a per-digit prefix over
//             the threads (in order) and over the thread's own run keeps equal digits in input
//             order, so the sort is stable and equal keys keep the order of their values.
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
  uint first = b * kBlockItems + t * kThreadItems;
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint i = first + k;
    if (i < u_count) atomicAdd(block_counts[digit_of(keys_in[i])], 1u);
  }
  barrier();
  if (t < kDigits) counts[t * u_blocks + b] = block_counts[t];
}
)";

constexpr const char* kScan = R"(
shared uint partial[kThreads];
void main() {
  uint t = gl_LocalInvocationID.x;
  uint n = kDigits * u_blocks, per = (n + kThreads - 1u) / kThreads, begin = min(t * per, n),
       end = min(begin + per, n);
  uint sum = 0u;
  for (uint i = begin; i < end; ++i) sum += counts[i];
  partial[t] = sum;
  barrier();
  if (t == 0u) {
    uint running = 0u;
    for (uint j = 0u; j < kThreads; ++j) {
      uint c = partial[j];
      partial[j] = running;
      running += c;
    }
  }
  barrier();
  uint running = partial[t];
  for (uint i = begin; i < end; ++i) {
    uint c = counts[i];
    counts[i] = running;
    running += c;
  }
}
)";

constexpr const char* kScatter = R"(
shared uint before[kDigits * kThreads];  // [digit * kThreads + thread]: that digit's pairs in earlier threads' runs
void main() {
  uint t = gl_LocalInvocationID.x, b = gl_WorkGroupID.x;
  uint first = b * kBlockItems + t * kThreadItems;
  uint mine[kDigits];
  for (uint d = 0u; d < kDigits; ++d) mine[d] = 0u;
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint i = first + k;
    if (i < u_count) mine[digit_of(keys_in[i])] += 1u;
  }
  for (uint d = 0u; d < kDigits; ++d) before[d * kThreads + t] = mine[d];
  barrier();
  if (t < kDigits) {
    uint running = 0u;
    for (uint j = 0u; j < kThreads; ++j) {
      uint c = before[t * kThreads + j];
      before[t * kThreads + j] = running;
      running += c;
    }
  }
  barrier();
  uint at[kDigits];
  for (uint d = 0u; d < kDigits; ++d) at[d] = counts[d * u_blocks + b] + before[d * kThreads + t];
  for (uint k = 0u; k < kThreadItems; ++k) {
    uint i = first + k;
    if (i < u_count) {
      uint key = keys_in[i];
      uint d = digit_of(key);
      uint o = at[d];
      at[d] = o + 1u;
      keys_out[o] = key;
      values_out[o] = values_in[i];
    }
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
  d.scan = program({kPrelude, kScan});
  d.scatter = program({kPrelude, kScatter});
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
