// Where a clip's bytes come from: the layer below the format. Every reader of .pstream bytes (the
// format's Reader, `info`, `verify`, the stream, the C API's clip and player, Python) takes a
// ByteSource: a local file (pread), the host's callbacks (the C API's pstream_io), or an
// http(s):// URL (range requests through libcurl; docs/streaming.md has the rules).
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <string_view>

#include "particlestream/error.hpp"

namespace pstream::io {

// What a source has done since it was opened (zeros for sources that do not count).
struct SourceStats {
  std::uint64_t requests = 0;   // reads sent (HTTP: range requests, retries included)
  std::uint64_t bytes = 0;      // bytes received
  std::uint64_t retries = 0;    // requests sent again after a transient failure
  double latency_ms = 0;        // time to the first byte, mean over requests
  double bandwidth_mb_s = 0;    // bytes over the time requests were in flight (MB/s)
  std::uint32_t in_flight = 0;  // reads under way now
  std::uint64_t cancelled = 0;  // reads ended early by cancel()
  std::uint64_t merged = 0;     // reads that rode in another read's request (adjacent ranges merged)
};

// A read-only source of bytes at offsets.
//
// read() fills `out` from `offset` completely or throws pstream::Error naming the source, the
// offset and the cause. It runs on whatever thread calls it (the stream's IO worker).
//
// A source whose reads complete elsewhere (an engine's streaming system, HTTP) also overrides
// start_read(): it starts the read, returns true at once, and calls `done(context, status)`
// exactly once, from any thread, when `out` is filled (status 0) or the read failed (non-zero:
// failure_message(status) then says why); `out` stays valid until then.
class ByteSource {
 public:
  using ReadDone = void (*)(void* context, int status);
  virtual ~ByteSource() = default;
  virtual void read(std::uint64_t offset, std::span<std::byte> out) = 0;
  virtual bool start_read(std::uint64_t /*offset*/, std::span<std::byte> /*out*/, ReadDone /*done*/,
                          void* /*context*/) {
    return false;
  }
  virtual std::uint64_t size() const = 0;
  virtual const std::string& name() const = 0;  // the path or URL, as messages give it
  // Why an asynchronous read failed with `status` (empty: the source keeps no message).
  virtual std::string failure_message(int /*status*/) const { return {}; }
  // A host that breaks start_read()'s contract: a completion called twice, or one that has not
  // come within the source's timeout. Empty while all is well; otherwise the message the stream
  // fails with.
  virtual std::string fault() const { return {}; }
  // Called by the stream's close() when a read never completed (fault() said so): completions
  // that come later must be ignored.
  virtual void abandon() {}
  // How many reads of `read_bytes` each the stream should keep under way (1: a local disk; HTTP:
  // enough to keep its connections busy with requests of about 1 MiB once neighbours are merged).
  virtual unsigned preferred_reads_in_flight(std::uint64_t /*read_bytes*/) const { return 1; }
  // The whole source in memory when it is (a mapped local file); empty otherwise.
  virtual std::span<const std::byte> mapped() const { return {}; }
  // The asynchronous read started with `context` is no longer wanted (a seek made it useless). A
  // source may end it early; its completion still comes exactly once, later and from its own
  // thread, with a failure status. Never calls the completion from inside cancel(). A context
  // with no read under way is ignored.
  virtual void cancel(void* /*context*/) {}
  virtual SourceStats stats() const { return {}; }
};

// The HTTP(S) source's settings (docs/streaming.md).
struct HttpOptions {
  unsigned connections = 6;         // reads in flight to the host
  unsigned retries = 4;             // transient failures retried per read (timeouts, 5xx, resets)
  double retry_base_seconds = 0.1;  // backoff: base x 2^attempt, with full jitter, capped below
  double retry_max_seconds = 2.0;
  double connect_timeout_seconds = 10;      // per request
  double stall_timeout_seconds = 10;        // a request that receives nothing for this long is retried,
  unsigned stall_retries = 1;               // this many times (within `retries`)
  std::uint64_t prefix_bytes = 256 * 1024;  // fetched at open (header and tables usually fit)
  // Reads waiting for a connection whose ranges lie at most merge_gap bytes apart go out as one
  // request of at most merge_bytes (the bytes between them are fetched and dropped; 0: never).
  std::uint64_t merge_bytes = 4 << 20;
  std::uint64_t merge_gap = 64 * 1024;
};

// "http://" or "https://" (case-insensitive).
bool is_url(std::string_view location);
// Whether this build has the HTTP(S) source (libcurl).
bool http_supported();

// A local file: regular files only (a FIFO or device is refused, never waited on); pread.
std::unique_ptr<ByteSource> open_file(const std::filesystem::path& path);
// A mapped local file (readers then read in place; mapped() is the file).
std::unique_ptr<ByteSource> open_mapped_file(const std::filesystem::path& path);
// An http(s):// URL: fetches the first prefix_bytes (learning the size, ETag and Last-Modified),
// then range requests. Throws pstream::Error naming the URL for a server that refuses, does not
// answer, or does not serve ranges.
std::unique_ptr<ByteSource> open_url(const std::string& url, const HttpOptions& options = {});
// A URL or a local path.
std::unique_ptr<ByteSource> open(const std::string& location);

}  // namespace pstream::io
