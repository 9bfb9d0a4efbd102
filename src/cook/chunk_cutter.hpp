// Cuts the logical record stream into chunks as records are written into it.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <functional>
#include <memory>
#include <span>

namespace pstream::cook {

// Chunks of `chunk_size` bytes are handed on in pieces of `buffer_size` bytes (a power of two
// that divides the chunk size), through emit(piece, ends_chunk). A buffer as large as a chunk
// gives whole chunks (for encoders); a small one stays in cache while raw pieces are written.
// The buffer is not zeroed: every byte emitted has been written by room()/commit() or write().
class ChunkCutter {
 public:
  using Emit = std::function<void(std::span<const std::byte> piece, bool ends_chunk)>;
  ChunkCutter(std::size_t chunk_size, std::size_t buffer_size, Emit emit)
      : chunk_size_(chunk_size),
        size_(std::min(buffer_size, chunk_size)),
        buffer_(new std::byte[size_]),
        emit_(std::move(emit)) {}

  // The free space at the write position, in whole records of `record_size` bytes; empty when
  // the next record would straddle a border (write() it). commit() says how much was filled.
  // A full buffer is emitted only when more bytes come, so uncommitted room is never emitted.
  std::span<std::byte> room(std::size_t record_size) {
    if (fill_ == size_) flush(false);
    const std::size_t whole = (size_ - fill_) / record_size * record_size;
    return {buffer_.get() + fill_, whole};
  }
  void commit(std::size_t n) { fill_ += n; }

  void write(const std::byte* data, std::size_t n) {
    while (n > 0) {
      if (fill_ == size_) flush(false);
      const std::size_t take = std::min(n, size_ - fill_);
      std::memcpy(buffer_.get() + fill_, data, take);
      data += take;
      n -= take;
      fill_ += take;
    }
  }

  // Emits what is buffered as the end of the last chunk.
  void finish() { flush(true); }

 private:
  void flush(bool last) {
    if (fill_ == 0) return;
    chunk_fill_ += fill_;
    const bool ends_chunk = last || chunk_fill_ == chunk_size_;
    emit_(std::span(buffer_.get(), fill_), ends_chunk);
    if (ends_chunk) chunk_fill_ = 0;
    fill_ = 0;
  }
  std::size_t chunk_size_, size_;
  std::unique_ptr<std::byte[]> buffer_;
  std::size_t fill_ = 0, chunk_fill_ = 0;
  Emit emit_;
};

}  // namespace pstream::cook
