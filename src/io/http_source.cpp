// http(s):// URLs as byte sources, on libcurl. The rules (docs/streaming.md):
// - one range per request (S3-like stores answer no more), "Accept-Encoding: identity", no
//   If-Match (it would make browsers send CORS preflights; we compare validators ourselves);
// - a response must be 206 with exactly the Content-Range asked for, the size seen at open, and
//   the ETag and Last-Modified seen at open; a 200 (the whole file), 416 or a changed validator
//   means the server does not serve ranges or the file changed: the read fails at once;
// - timeouts, connection resets, short bodies, 408, 429 and 5xx are retried with exponential
//   backoff and full jitter, HttpOptions::retries times per read;
// - a body longer than asked for is cut off (never read to its end);
// - reads waiting for a connection whose ranges lie at most merge_gap apart go out as one request
//   of at most merge_bytes, whose body is split between them (PMTiles and COPC readers do this);
// - every message names the URL, the byte range and the cause.
// One thread per source drives a curl multi handle: up to `connections` requests in flight, kept
// alive and reused (HTTP/2 when the server offers it over TLS), redirects followed.
#include <curl/curl.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <charconv>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <random>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "particlestream/io.hpp"

namespace pstream::io {
namespace {

using Clock = std::chrono::steady_clock;

// Reads the stream may keep queued per connection (small chunks): what the pool is sized for.
constexpr std::uint64_t kReadsPerConnection = 4;

void global_init() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (curl_global_init(CURL_GLOBAL_DEFAULT) != CURLE_OK) throw Error("libcurl failed to initialise");
  });
}

// Case-insensitive equality of ASCII text (header names, schemes), allocating nothing.
bool iequals(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const auto fold = [](char c) { return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c; };
    if (fold(a[i]) != fold(b[i])) return false;
  }
  return true;
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == '\r' || s.back() == '\n' || s.back() == ' ' || s.back() == '\t'))
    s.remove_suffix(1);
  return s;
}

// "bytes FIRST-LAST/TOTAL" (TOTAL may be "*"): false when it is not that.
bool parse_content_range(std::string_view v, std::uint64_t& first, std::uint64_t& last, std::uint64_t& total) {
  v = trim(v);
  if (v.size() < 6 || !iequals(v.substr(0, 6), "bytes ")) return false;
  v.remove_prefix(6);
  const auto num = [&](std::uint64_t& out, char end) {
    const auto r = std::from_chars(v.data(), v.data() + v.size(), out);
    if (r.ec != std::errc() || r.ptr == v.data() + v.size() || *r.ptr != end) return false;
    v.remove_prefix(static_cast<std::size_t>(r.ptr - v.data()) + 1);
    return true;
  };
  if (!num(first, '-') || !num(last, '/')) return false;
  const auto r = std::from_chars(v.data(), v.data() + v.size(), total);
  return r.ec == std::errc() && r.ptr == v.data() + v.size() && last >= first;
}

class HttpSource;

// One read: a range, where its bytes go, and what its responses said.
struct Request {
  HttpSource* owner = nullptr;
  std::uint64_t offset = 0;
  std::span<std::byte> out;
  ByteSource::ReadDone done = nullptr;
  void* context = nullptr;
  bool probe = false;  // the first request at open: any length up to out.size(), learns the size
  unsigned attempt = 0, stalls = 0;
  bool cancelled = false;  // cancel() asked: ended by the run loop, never retried
  // Merged neighbours: the reads riding in this request, in offset order (a chain through the
  // pool, so merging allocates nothing). `span` is what the request asks for: from `offset` to
  // the end of its last read; `fill` is the read the body is being written into.
  Request* next = nullptr;
  Request* fill = nullptr;
  std::uint64_t span = 0;
  // A merged request whose headers hold completes each read as soon as its last byte is in
  // (`early`), not when the whole request ends; `completed` marks a read so done.
  bool early = false;
  bool completed = false;
  Clock::time_point not_before{};
  // The current response.
  long status = 0;
  std::string content_range, etag, last_modified;
  std::uint64_t received = 0;
  bool overflow = false;  // the body went past the range, or a 200 began: cut off
  char curl_error[CURL_ERROR_SIZE] = {};
  char range[48] = {};  // "FIRST-LAST"
  CURL* easy = nullptr;
};

class HttpSource final : public ByteSource {
 public:
  HttpSource(std::string url, const HttpOptions& options) : url_(std::move(url)), o_(options) {
    global_init();
    o_.connections = std::max(1u, o_.connections);
    multi_ = curl_multi_init();
    if (multi_ == nullptr) throw Error(url_ + ": libcurl could not make a multi handle");
    curl_multi_setopt(multi_, CURLMOPT_MAX_HOST_CONNECTIONS, static_cast<long>(o_.connections));
    curl_multi_setopt(multi_, CURLMOPT_MAX_TOTAL_CONNECTIONS, static_cast<long>(o_.connections));
    // A fixed pool of requests and easy handles, made here: reading allocates nothing of ours.
    // The stream's reads, a head per connection whose reads completed early while its request
    // runs on, and the two synchronous reads at open.
    pool_.resize(std::size_t{o_.connections} * (kReadsPerConnection + 1) + 2);
    free_.reserve(pool_.size());
    queue_.reserve(pool_.size());
    active_.reserve(pool_.size());
    ended_.reserve(pool_.size());
    for (Request& r : pool_) {
      r.easy = curl_easy_init();
      if (r.easy == nullptr) {
        release();
        throw Error(url_ + ": libcurl could not make an easy handle");
      }
      for (std::string* text : {&r.content_range, &r.etag, &r.last_modified}) text->reserve(256);
      r.owner = this;
      free_.push_back(&r);
    }
    thread_ = std::thread([this] { run(); });
    try {
      probe();
    } catch (...) {  // no destructor runs for a constructor that throws: release here
      release();
      throw;
    }
  }
  ~HttpSource() override { release(); }
  HttpSource(const HttpSource&) = delete;
  HttpSource& operator=(const HttpSource&) = delete;

  void read(std::uint64_t offset, std::span<std::byte> out) override {
    if (serve_from_prefix(offset, out)) return;
    struct Wait {
      std::mutex m;
      std::condition_variable cv;
      bool done = false;
      int status = 0;
    } wait;
    const auto done = [](void* context, int status) {
      auto* w = static_cast<Wait*>(context);
      std::lock_guard lock(w->m);
      w->done = true;
      w->status = status;
      w->cv.notify_all();
    };
    if (!submit(offset, out, done, &wait, false)) throw Error(fmt::format("{}: too many reads under way", url_));
    std::unique_lock lock(wait.m);
    wait.cv.wait(lock, [&] { return wait.done; });
    if (wait.status != 0) throw Error(failure_message(wait.status));
  }

  bool start_read(std::uint64_t offset, std::span<std::byte> out, ReadDone done, void* context) override {
    if (serve_from_prefix(offset, out)) return false;  // read() copies it at once
    return submit(offset, out, done, context, false);
  }

  std::uint64_t size() const override { return size_; }
  const std::string& name() const override { return url_; }
  // Small reads are worth queueing beyond the connections: queued neighbours merge into
  // requests of about 1 MiB, so one round trip carries more than one small chunk.
  unsigned preferred_reads_in_flight(std::uint64_t read_bytes) const override {
    const std::uint64_t per_connection =
        std::clamp<std::uint64_t>((1u << 20) / std::max<std::uint64_t>(read_bytes, 1), 1, kReadsPerConnection);
    return o_.connections * static_cast<unsigned>(per_connection);
  }
  std::string failure_message(int status) const override {
    std::lock_guard lock(mutex_);
    if (status <= 0 || static_cast<std::size_t>(status) > messages_.size()) return {};
    return messages_[static_cast<std::size_t>(status) - 1];
  }
  void cancel(void* context) override {
    bool found = false;
    {
      std::lock_guard lock(mutex_);
      for (const auto* list : {&queue_, &active_}) {
        for (Request* r : *list) {
          for (Request* m = r; m != nullptr; m = m->next)
            found = found || (m->context == context && (m->cancelled = true));
        }
      }
    }
    if (found) curl_multi_wakeup(multi_);  // the run loop ends it
  }

  SourceStats stats() const override {
    std::lock_guard lock(mutex_);
    SourceStats s = stats_;
    s.latency_ms = latency_count_ ? latency_sum_ms_ / double(latency_count_) : 0.0;
    s.bandwidth_mb_s = transfer_seconds_ > 0 ? double(s.bytes) / transfer_seconds_ / 1e6 : 0.0;
    for (const auto* list : {&queue_, &active_}) {
      for (const Request* r : *list) {
        for (const Request* m = r; m != nullptr; m = m->next) s.in_flight += m->completed ? 0 : 1;
      }
    }
    return s;
  }

 private:
  // The first request: the first prefix_bytes, which also say the size and the validators.
  void probe() {
    prefix_.resize(o_.prefix_bytes);
    read_probe_ = true;
    ByteSource::ReadDone done = [](void* context, int status) {
      auto* self = static_cast<HttpSource*>(context);
      std::lock_guard lock(self->probe_mutex_);
      self->probe_status_ = status;
      self->probe_done_ = true;
      self->probe_cv_.notify_all();
    };
    submit(0, prefix_, done, this, true);
    std::unique_lock lock(probe_mutex_);
    probe_cv_.wait(lock, [&] { return probe_done_; });
    if (probe_status_ != 0) throw Error(failure_message(probe_status_));
    read_probe_ = false;
  }

  bool serve_from_prefix(std::uint64_t offset, std::span<std::byte> out) {
    if (read_probe_ || offset > prefix_size_ || out.size() > prefix_size_ - offset) return false;
    std::memcpy(out.data(), prefix_.data() + offset, out.size());
    return true;
  }

  bool submit(std::uint64_t offset, std::span<std::byte> out, ReadDone done, void* context, bool probe) {
    {
      std::lock_guard lock(mutex_);
      if (free_.empty() || stopping_) return false;
      Request* r = free_.back();
      free_.pop_back();
      r->offset = offset;
      r->out = out;
      r->done = done;
      r->context = context;
      r->probe = probe;
      r->attempt = 0;
      r->stalls = 0;
      r->cancelled = false;
      r->next = nullptr;
      r->span = out.size();
      r->completed = false;
      r->not_before = Clock::now();
      queue_.push_back(r);
    }
    curl_multi_wakeup(multi_);
    return true;
  }

  void release() {
    stop();
    for (Request& r : pool_) {
      if (r.easy != nullptr) curl_easy_cleanup(r.easy);
      r.easy = nullptr;
    }
    if (multi_ != nullptr) curl_multi_cleanup(multi_);
    multi_ = nullptr;
  }

  void stop() {
    {
      std::lock_guard lock(mutex_);
      stopping_ = true;
    }
    curl_multi_wakeup(multi_);
    if (thread_.joinable()) thread_.join();
  }

  static std::size_t on_header(char* data, std::size_t size, std::size_t n, void* user) {
    auto* r = static_cast<Request*>(user);
    const std::string_view line(data, size * n);
    if (line.size() >= 5 && iequals(line.substr(0, 5), "http/")) {  // a new response (after a redirect)
      r->content_range.clear();
      r->etag.clear();
      r->last_modified.clear();
      return size * n;
    }
    const std::size_t colon = line.find(':');
    if (colon == std::string_view::npos) return size * n;
    const std::string_view key = trim(line.substr(0, colon));
    const std::string_view value = trim(line.substr(colon + 1));
    // Assigned into strings whose capacity the first responses set: no allocation per request.
    if (iequals(key, "content-range")) r->content_range.assign(value);
    if (iequals(key, "etag")) r->etag.assign(value);
    if (iequals(key, "last-modified")) r->last_modified.assign(value);
    return size * n;
  }

  static std::size_t on_body(char* data, std::size_t size, std::size_t n, void* user) {
    auto* r = static_cast<Request*>(user);
    const std::size_t bytes = size * n;
    long status = 0;
    curl_easy_getinfo(r->easy, CURLINFO_RESPONSE_CODE, &status);
    if (status != 206 && status != 0) {  // a 200 is the whole file (or an error page): not read
      r->overflow = true;
      return 0;
    }
    if (r->received + bytes > r->span) {  // longer than the range: refused, never read on
      r->overflow = true;
      return 0;
    }
    if (r->received == 0 && r->next != nullptr) {
      std::uint64_t got = 0, total = 0;
      r->early = r->owner->range_problem(*r, got, total).empty();
    }
    // Into the read that holds each byte; bytes between merged reads are dropped.
    for (std::size_t used = 0; used < bytes;) {
      const std::uint64_t at = r->offset + r->received + used;
      while (r->fill != nullptr && at >= r->fill->offset + r->fill->out.size()) r->fill = r->fill->next;
      Request* f = r->fill;
      if (f == nullptr) {  // past the last read: cannot be, the span ends where it ends
        r->overflow = true;
        return 0;
      }
      if (at < f->offset) {
        used += static_cast<std::size_t>(std::min<std::uint64_t>(bytes - used, f->offset - at));
        continue;
      }
      const auto n = static_cast<std::size_t>(std::min<std::uint64_t>(bytes - used, f->offset + f->out.size() - at));
      std::memcpy(f->out.data() + (at - f->offset), data + used, n);
      used += n;
      // A read whose bytes are all in needs not wait for its neighbours' (the request's last
      // read completes when the request ends, as a lone read does).
      if (r->early && f->next != nullptr && at + n == f->offset + f->out.size()) {
        // Reads complete in order, so every read before f is done: a follower leaves the chain
        // and goes back to the pool now (the request keeps only its head), so reads completed
        // early never pile up while their requests run on.
        const ReadDone done = f->done;
        void* context = f->context;
        const std::uint64_t first = f->offset, size = f->out.size();
        bool cancelled = false;
        {
          std::lock_guard lock(r->owner->mutex_);
          cancelled = f->cancelled;
          f->completed = true;
          if (f != r) {
            r->next = f->next;
            r->fill = f->next;
            f->next = nullptr;
            r->owner->free_.push_back(f);
          }
        }
        // Outside mutex_: the message keeps its own lock, and a completion may start or cancel reads.
        done(context, cancelled ? r->owner->cancelled_status(first, size) : 0);
      }
    }
    r->received += bytes;
    return bytes;
  }

  void prepare(Request& r) {
    CURL* e = r.easy;
    curl_easy_reset(e);
    r.status = 0;
    r.received = 0;
    r.fill = &r;
    r.early = false;
    r.overflow = false;
    r.content_range.clear();
    r.etag.clear();
    r.last_modified.clear();
    r.curl_error[0] = '\0';
    fmt::format_to_n(r.range, sizeof r.range - 1, "{}-{}", r.offset, r.offset + r.span - 1).out[0] = '\0';
    curl_easy_setopt(e, CURLOPT_URL, url_.c_str());
    curl_easy_setopt(e, CURLOPT_RANGE, r.range);
    curl_easy_setopt(e, CURLOPT_ACCEPT_ENCODING, "identity");
    curl_easy_setopt(e, CURLOPT_FOLLOWLOCATION, 1L);
    curl_easy_setopt(e, CURLOPT_MAXREDIRS, 8L);
    curl_easy_setopt(e, CURLOPT_HTTP_VERSION, static_cast<long>(CURL_HTTP_VERSION_2TLS));
    curl_easy_setopt(e, CURLOPT_NOSIGNAL, 1L);
    curl_easy_setopt(e, CURLOPT_CONNECTTIMEOUT_MS, static_cast<long>(o_.connect_timeout_seconds * 1000));
    // Nothing received for stall_timeout seconds: a stalled request, retried.
    curl_easy_setopt(e, CURLOPT_LOW_SPEED_LIMIT, 1L);
    curl_easy_setopt(e, CURLOPT_LOW_SPEED_TIME, std::max(1L, static_cast<long>(o_.stall_timeout_seconds)));
    curl_easy_setopt(e, CURLOPT_HEADERFUNCTION, &HttpSource::on_header);
    curl_easy_setopt(e, CURLOPT_HEADERDATA, &r);
    curl_easy_setopt(e, CURLOPT_WRITEFUNCTION, &HttpSource::on_body);
    curl_easy_setopt(e, CURLOPT_WRITEDATA, &r);
    curl_easy_setopt(e, CURLOPT_ERRORBUFFER, r.curl_error);
    curl_easy_setopt(e, CURLOPT_PRIVATE, &r);
    curl_easy_setopt(e, CURLOPT_USERAGENT, "ParticleStream");
  }

  // What is wrong with a 206's headers (empty: nothing): its Content-Range must be the range asked
  // for, and (after the probe) the size and validators those seen at open.
  std::string range_problem(const Request& r, std::uint64_t& got_len, std::uint64_t& total) const {
    std::uint64_t first = 0, last = 0;
    if (!parse_content_range(r.content_range, first, last, total)) {
      return fmt::format("a 206 without a valid Content-Range (got '{}')", r.content_range);
    }
    got_len = last - first + 1;
    if (first != r.offset || (r.probe ? got_len > r.span : got_len != r.span)) {
      return fmt::format("Content-Range '{}' is not the range asked for", r.content_range);
    }
    if (r.probe) return {};
    if (total != size_)
      return fmt::format("the file is now {} bytes, {} when it was opened (it changed)", total, size_);
    if ((!etag_.empty() && r.etag != etag_) || (!last_modified_.empty() && r.last_modified != last_modified_)) {
      return fmt::format("the file changed since it was opened (ETag {} / Last-Modified {}, was {} / {})",
                         r.etag.empty() ? "none" : r.etag, r.last_modified.empty() ? "none" : r.last_modified,
                         etag_.empty() ? "none" : etag_, last_modified_.empty() ? "none" : last_modified_);
    }
    return {};
  }

  // What a finished transfer means: 0 (the bytes are in), or a message and whether to retry.
  struct Outcome {
    bool ok = false, transient = false;
    std::string why;
  };
  Outcome judge(Request& r, CURLcode code) {
    Outcome o;
    curl_easy_getinfo(r.easy, CURLINFO_RESPONSE_CODE, &r.status);
    const std::uint64_t want = r.span;
    // A body cut off on purpose: the whole file (200), or more than the range (206). Other
    // statuses' bodies (error pages) were cut off too; their status decides below.
    if (r.overflow && (r.status == 200 || r.status == 206)) {
      o.why = r.status == 200 ? "the server answered 200 with the whole file instead of 206 Partial Content (it does "
                                "not serve range requests, or ignored this one)"
                              : fmt::format("the body is longer than the {} bytes asked for", want);
      return o;
    }
    if (code != CURLE_OK && !(code == CURLE_WRITE_ERROR && r.overflow)) {
      o.transient = code == CURLE_OPERATION_TIMEDOUT || code == CURLE_COULDNT_CONNECT || code == CURLE_RECV_ERROR ||
                    code == CURLE_SEND_ERROR || code == CURLE_PARTIAL_FILE || code == CURLE_GOT_NOTHING ||
                    code == CURLE_HTTP2 || code == CURLE_HTTP2_STREAM || code == CURLE_WEIRD_SERVER_REPLY;
      o.why = r.curl_error[0] ? std::string(r.curl_error) : curl_easy_strerror(code);
      return o;
    }
    if (r.status == 408 || r.status == 429 || r.status >= 500) {
      o.transient = true;
      o.why = fmt::format("HTTP {}", r.status);
      return o;
    }
    if (r.status == 416) {
      o.why = "HTTP 416 (range not satisfiable): the file is shorter than when it was opened (it changed)";
      return o;
    }
    if (r.status != 206) {
      o.why = r.status == 404   ? "HTTP 404 (not found)"
              : r.status == 403 ? "HTTP 403 (forbidden)"
              : r.status == 200 ? "the server answered 200 instead of 206 Partial Content (it does not serve ranges)"
                                : fmt::format("HTTP {} where 206 Partial Content was expected", r.status);
      return o;
    }
    std::uint64_t got_len = 0, total = 0;
    o.why = range_problem(r, got_len, total);
    if (!o.why.empty()) return o;
    if (r.received != got_len) {
      o.transient = true;
      o.why = fmt::format("a short body: {} of {} bytes", r.received, got_len);
      return o;
    }
    if (r.probe) {
      size_ = total;
      prefix_size_ = got_len;
      etag_ = r.etag;
      last_modified_ = r.last_modified;
    }
    o.ok = true;
    return o;
  }

  // Keeps `message` for failure_message(); returns its status (1-based, in a ring of 16).
  int keep_message(std::string message) {
    std::lock_guard lock(mutex_);
    if (messages_.size() < 16) {
      messages_.push_back(std::move(message));
      return static_cast<int>(messages_.size());
    }
    next_message_ = (next_message_ + 1) % messages_.size();
    messages_[next_message_] = std::move(message);
    return static_cast<int>(next_message_ + 1);
  }

  void finish(Request* r, CURLcode code) {
    const Outcome o = judge(*r, code);
    double start_s = 0, total_s = 0;
    curl_easy_getinfo(r->easy, CURLINFO_STARTTRANSFER_TIME, &start_s);
    curl_easy_getinfo(r->easy, CURLINFO_TOTAL_TIME, &total_s);
    {
      std::lock_guard lock(mutex_);
      ++stats_.requests;
      stats_.bytes += r->received;
      if (start_s > 0) {
        latency_sum_ms_ += start_s * 1000;
        ++latency_count_;
      }
      transfer_seconds_ += total_s;
    }
    // A request that stalled (nothing for stall_timeout) is tried again stall_retries times at
    // most: a server that accepts and never answers is dead, not busy.
    const bool stalled = code == CURLE_OPERATION_TIMEDOUT;
    if (stalled) ++r->stalls;
    if (!o.ok && o.transient && r->attempt < o_.retries && (!stalled || r->stalls <= o_.stall_retries)) {
      // Exponential backoff with full jitter.
      const double cap =
          std::min(o_.retry_max_seconds, o_.retry_base_seconds * double(1u << std::min(r->attempt, 16u)));
      const double wait = std::uniform_real_distribution<double>(0.0, cap)(rng_);
      ++r->attempt;
      r->not_before = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(wait));
      std::lock_guard lock(mutex_);
      ++stats_.retries;
      // Each read not yet completed goes back alone; due together, they merge again when they go out.
      for (Request* m = r; m != nullptr;) {
        Request* const next = m->next;
        m->next = nullptr;
        if (m->completed) {
          free_.push_back(m);
          m = next;
          continue;
        }
        m->span = m->out.size();
        m->attempt = r->attempt;
        m->stalls = r->stalls;
        m->not_before = r->not_before;
        queue_.push_back(m);
        m = next;
      }
      return;
    }
    const std::uint64_t first = r->offset, last = r->offset + r->span - 1;
    const bool merged = r->next != nullptr;
    const unsigned attempts = r->attempt;
    complete_all(r, [&](const Request& m) {
      if (m.cancelled) return cancelled_status(m);
      if (o.ok) return 0;
      return keep_message(
          fmt::format("{}: bytes {}-{}: {}{}{}", url_, m.offset, m.offset + m.out.size() - 1, o.why,
                      attempts ? fmt::format(" (after {} {})", attempts, attempts == 1 ? "retry" : "retries") : "",
                      merged ? fmt::format(" (in one request for bytes {}-{})", first, last) : ""));
    });
  }

  int cancelled_status(std::uint64_t offset, std::uint64_t size) {
    return keep_message(fmt::format("{}: bytes {}-{}: cancelled (no longer wanted)", url_, offset, offset + size - 1));
  }
  int cancelled_status(const Request& m) { return cancelled_status(m.offset, m.out.size()); }

  // Hands every read of the request `r` back to the pool and completes the ones not completed
  // early; status(read) says how (0: its bytes are in). A completion may start reads that reuse
  // these requests at once.
  template <typename Status>
  void complete_all(Request* r, Status&& status) {
    for (Request* m = r; m != nullptr;) {
      Request* const next = m->next;
      const bool completed = m->completed;
      const int st = completed ? 0 : status(*m);
      const ReadDone done = m->done;
      void* context = m->context;
      m->next = nullptr;
      {
        std::lock_guard lock(mutex_);
        free_.push_back(m);
      }
      if (!completed) done(context, st);
      m = next;
    }
  }

  // Takes the due reads that continue `r` (at most merge_gap bytes after its end, the whole
  // request within merge_bytes) out of the queue and chains them to it. Under mutex_.
  void merge_neighbours(Request& r, Clock::time_point now) {
    if (r.probe) return;
    Request* tail = &r;
    for (;;) {
      const std::uint64_t end = r.offset + r.span;
      auto best = queue_.end();
      for (auto it = queue_.begin(); it != queue_.end(); ++it) {
        const Request* q = *it;
        if (q->probe || q->cancelled || q->not_before > now || q->offset < end || q->offset - end > o_.merge_gap ||
            q->offset + q->out.size() - r.offset > o_.merge_bytes)
          continue;
        if (best == queue_.end() || q->offset < (*best)->offset) best = it;
      }
      if (best == queue_.end()) return;
      Request* q = *best;
      queue_.erase(best);
      tail->next = q;
      tail = q;
      r.span = q->offset + q->out.size() - r.offset;
      ++stats_.merged;
    }
  }

  void run() {
    for (;;) {
      // Start the requests that are due, up to `connections` at once; end the cancelled ones.
      int wait_ms = 1000;
      ended_.clear();  // reserved at open: the run thread's own
      {
        std::lock_guard lock(mutex_);
        if (stopping_) break;
        // A request ends early only when every read riding in it is cancelled.
        for (auto* list : {&active_, &queue_}) {
          for (auto it = list->begin(); it != list->end();) {
            bool all = true;
            for (const Request* m = *it; m != nullptr; m = m->next) all = all && (m->cancelled || m->completed);
            if (!all) {
              ++it;
              continue;
            }
            if (list == &active_) curl_multi_remove_handle(multi_, (*it)->easy);
            for (const Request* m = *it; m != nullptr; m = m->next) stats_.cancelled += m->completed ? 0 : 1;
            ended_.push_back(*it);
            it = list->erase(it);
          }
        }
        const auto now = Clock::now();
        for (const Request* r : queue_) {
          if (r->not_before <= now) continue;
          const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(r->not_before - now).count();
          wait_ms = std::min<int>(wait_ms, static_cast<int>(ms) + 1);
        }
        while (active_.size() < o_.connections) {
          const auto due =
              std::find_if(queue_.begin(), queue_.end(), [&](const Request* q) { return q->not_before <= now; });
          if (due == queue_.end()) break;
          Request* r = *due;
          queue_.erase(due);
          merge_neighbours(*r, now);
          prepare(*r);
          curl_multi_add_handle(multi_, r->easy);
          active_.push_back(r);
        }
      }
      for (Request* r : ended_) complete_all(r, [&](const Request& m) { return cancelled_status(m); });
      int running = 0;
      curl_multi_perform(multi_, &running);
      int left = 0;
      while (CURLMsg* m = curl_multi_info_read(multi_, &left)) {
        if (m->msg != CURLMSG_DONE) continue;
        Request* r = nullptr;
        curl_easy_getinfo(m->easy_handle, CURLINFO_PRIVATE, reinterpret_cast<char**>(&r));
        const CURLcode code = m->data.result;
        curl_multi_remove_handle(multi_, m->easy_handle);
        {
          std::lock_guard lock(mutex_);
          active_.erase(std::find(active_.begin(), active_.end(), r));
        }
        finish(r, code);
        wait_ms = 0;  // a connection is free (or a retry queued): start what waits for it at once
      }
      curl_multi_poll(multi_, nullptr, 0, wait_ms, nullptr);
    }
    // Stopping: whatever is still under way fails (the owner is closing).
    std::vector<Request*> left;
    {
      std::lock_guard lock(mutex_);
      for (Request* r : active_) curl_multi_remove_handle(multi_, r->easy);
      left.insert(left.end(), active_.begin(), active_.end());
      left.insert(left.end(), queue_.begin(), queue_.end());
      active_.clear();
      queue_.clear();
    }
    for (Request* r : left) {
      complete_all(r, [&](const Request& m) {
        return keep_message(
            fmt::format("{}: closed while bytes {}-{} were being read", url_, m.offset, m.offset + m.out.size() - 1));
      });
    }
  }

  std::string url_;
  HttpOptions o_;
  std::uint64_t size_ = 0;
  std::string etag_, last_modified_;
  std::vector<std::byte> prefix_;
  std::uint64_t prefix_size_ = 0;
  std::atomic<bool> read_probe_{false};
  std::mutex probe_mutex_;
  std::condition_variable probe_cv_;
  bool probe_done_ = false;
  int probe_status_ = 0;

  CURLM* multi_ = nullptr;
  std::vector<Request> pool_;
  std::mt19937_64 rng_{std::random_device{}()};
  mutable std::mutex mutex_;  // guards what follows
  std::vector<Request*> free_;
  std::vector<Request*> queue_;  // reserved at open: queueing allocates nothing
  std::vector<Request*> active_;
  std::vector<Request*> ended_;  // cancelled requests being ended (the run thread's)
  std::vector<std::string> messages_;
  std::size_t next_message_ = 0;
  SourceStats stats_;
  double latency_sum_ms_ = 0, transfer_seconds_ = 0;
  std::uint64_t latency_count_ = 0;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace

bool http_supported() { return true; }

std::unique_ptr<ByteSource> open_url(const std::string& url, const HttpOptions& options) {
  return std::make_unique<HttpSource>(url, options);
}

}  // namespace pstream::io
