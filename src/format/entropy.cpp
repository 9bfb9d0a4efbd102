// The entropy stage with libzstd and liblz4 (entropy.hpp): what every native build links.
#define ZSTD_STATIC_LINKING_ONLY  // ZSTD_initStaticDStream, ZSTD_estimateDStreamSize, ZSTD_nextInputType
#include "format/entropy.hpp"

#include <lz4.h>
#include <zstd.h>

#include <climits>
#include <cstring>

#include "base/memory.hpp"
#include "format/zstd_memory.hpp"
#include "particlestream/error.hpp"

namespace pstream::format {

EntropyDecoder::EntropyDecoder(int stream_window_log) {
  if (stream_window_log <= 0) {
    state_ = make_zstd_dctx();
    if (state_ == nullptr) throw Error("cannot create a zstd decoder");
    return;
  }
  // A static context, which serves whole frames and the stream alike: zstd takes its window and
  // input buffers from this block and never allocates while decoding.
  const std::size_t bytes = stream_bytes(stream_window_log);
  void* block = memory::allocate(bytes);
  ZSTD_DCtx* d = block == nullptr ? nullptr : ZSTD_initStaticDStream(block, bytes);
  if (d == nullptr) {
    memory::deallocate(block);
    throw Error("cannot allocate the zstd stream decoder");
  }
  ZSTD_DCtx_setParameter(d, ZSTD_d_windowLogMax, stream_window_log);
  state_ = block;  // the context starts the block
  static_ = true;
  block_bytes_ = bytes;
}

EntropyDecoder::~EntropyDecoder() {
  if (static_)
    memory::deallocate(state_);  // a static context owns nothing else
  else
    ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(state_));
}

std::uint64_t EntropyDecoder::stream_bytes(int stream_window_log) {
  return stream_window_log <= 0 ? 0 : ZSTD_estimateDStreamSize(std::size_t{1} << stream_window_log);
}

std::size_t EntropyDecoder::zstd(std::span<std::byte> out, std::span<const std::byte> in, std::string& error) {
  const std::size_t n =
      ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(state_), out.data(), out.size(), in.data(), in.size());
  if (!ZSTD_isError(n)) return n;
  error = ZSTD_getErrorName(n);
  return kFailed;
}

std::size_t EntropyDecoder::zstd_stream(std::span<std::byte> out, std::span<const std::byte> in, bool restart,
                                        std::string& error) {
  auto* d = static_cast<ZSTD_DCtx*>(state_);
  if (!static_) {
    error = "this decoder holds no zstd stream";
    return kFailed;
  }
  if (restart) {
    ZSTD_DCtx_reset(d, ZSTD_reset_session_only);
    streaming_ = true;
  } else if (!streaming_) {
    error = "the stream's earlier data was not decoded just before";
    return kFailed;
  }
  streaming_ = false;  // until this piece decodes whole
  ZSTD_inBuffer src{in.data(), in.size(), 0};
  ZSTD_outBuffer dst{out.data(), out.size(), 0};
  while (src.pos < src.size) {
    const std::size_t r = ZSTD_decompressStream(d, &dst, &src);
    if (ZSTD_isError(r)) {
      error = ZSTD_getErrorName(r);
      return kFailed;
    }
    if (dst.pos == dst.size && src.pos < src.size) {
      error = "it decodes to more than the expected bytes";
      return kFailed;
    }
  }
  if (dst.pos == dst.size) {  // a body never fills its bound; the rest may still be held back
    error = "it decodes to more than the expected bytes";
    return kFailed;
  }
  const ZSTD_nextInputType_e next = ZSTD_nextInputType(d);
  if (next != ZSTDnit_blockHeader && next != ZSTDnit_frameHeader) {
    error = "the data ends inside a zstd block";
    return kFailed;
  }
  streaming_ = true;
  return dst.pos;
}

// A static context keeps everything it needs between packets in its own block: the window, its
// buffers, its entropy tables, and the pointers into them, which all point inside the block. A
// copy of the block, put back at the same address, is therefore the stream as it was (the codec
// tests check the frames decoded after a restore bit for bit against a straight decode).
bool EntropyDecoder::can_save_stream() { return true; }

std::uint64_t EntropyDecoder::saved_stream_bytes() const { return static_ ? block_bytes_ : 0; }

bool EntropyDecoder::save_stream(std::span<std::byte> to) const {
  if (!static_ || !streaming_ || to.size() < block_bytes_) return false;
  std::memcpy(to.data(), state_, block_bytes_);
  return true;
}

void EntropyDecoder::restore_stream(std::span<const std::byte> from) {
  if (!static_) return;
  streaming_ = from.size() >= block_bytes_;  // too few bytes: no stream to continue
  if (streaming_) std::memcpy(state_, from.data(), block_bytes_);
}

std::size_t EntropyDecoder::lz4(std::span<std::byte> out, std::span<const std::byte> in, std::string& error) {
  if (in.size() > INT_MAX || out.size() > INT_MAX) {
    error = "more than 2 GiB in one lz4 block";
    return kFailed;
  }
  const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(in.data()), reinterpret_cast<char*>(out.data()),
                                    static_cast<int>(in.size()), static_cast<int>(out.size()));
  if (n >= 0) return static_cast<std::size_t>(n);
  error = "it does not decode within the expected bytes";
  return kFailed;
}

}  // namespace pstream::format
