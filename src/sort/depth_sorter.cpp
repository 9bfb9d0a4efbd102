#include <algorithm>
#include <barrier>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <stdexcept>
#include <thread>

#include "particlestream/sort.hpp"
#include "radix.hpp"

namespace pstream::sort {
namespace {

// Items to sort ascending: key << 32 | index, with the key flipped for back-to-front so that the
// farthest particle comes first.
inline std::uint64_t item_for(float depth, std::uint32_t index, SortMode mode) {
  std::uint32_t key = order_preserving_key(depth);
  if (mode == SortMode::BackToFront) key = ~key;
  return static_cast<std::uint64_t>(key) << 32 | index;
}

inline std::uint64_t item16_for(float depth, std::uint32_t index, SortMode mode, float near, float scale) {
  const float t = std::clamp((depth - near) * scale, 0.0f, 1.0f);
  auto q = static_cast<std::uint32_t>(t * 65535.0f + 0.5f);
  if (mode == SortMode::BackToFront) q = 65535u - q;
  return static_cast<std::uint64_t>(q) << 32 | index;
}

constexpr int kBits = 8;
constexpr int kDigits = 4;
constexpr std::uint32_t kBuckets = 1u << kBits, kMask = kBuckets - 1;

}  // namespace

// One helper thread for the 2-thread variant: it runs the second half of every step, the
// caller the first; std::barrier keeps the steps in lock-step. Created once, reused every frame.
struct DepthSorter::Helper {
  std::barrier<> sync{2};
  std::mutex mutex;
  std::condition_variable wake;
  void (*job)(void*, int) = nullptr;  // no std::function: posting a job must not allocate
  void* context = nullptr;
  std::uint64_t posted = 0;
  std::uint32_t hist[2][kBuckets] = {};
  bool stop = false;
  std::jthread thread{[this] {
    std::uint64_t seen = 0;
    for (;;) {
      void (*todo)(void*, int) = nullptr;
      void* ctx = nullptr;
      {
        std::unique_lock lock(mutex);
        wake.wait(lock, [&] { return stop || posted != seen; });
        if (stop) return;
        seen = posted;
        todo = job;
        ctx = context;
      }
      todo(ctx, 1);
      sync.arrive_and_wait();  // tells run() this half is done
    }
  }};

  ~Helper() {
    {
      std::lock_guard lock(mutex);
      stop = true;
    }
    wake.notify_one();
  }

  // Runs work(0) here and work(1) on the helper; work calls sync.arrive_and_wait() between steps.
  template <class Work>
  void run(Work& work) {
    {
      std::lock_guard lock(mutex);
      job = [](void* c, int t) { (*static_cast<Work*>(c))(t); };
      context = &work;
      ++posted;
    }
    wake.notify_one();
    work(0);
    sync.arrive_and_wait();  // the helper has finished too
  }
};

DepthSorter::DepthSorter(std::size_t max_count, SorterOptions options)
    : capacity_(max_count),
      options_(options),
      depths_(new float[std::max<std::size_t>(max_count, 1)]),
      items_(new std::uint64_t[std::max<std::size_t>(max_count, 1)]),
      scratch_(new std::uint64_t[std::max<std::size_t>(max_count, 1)]),
      indices_(new std::uint32_t[std::max<std::size_t>(max_count, 1)]),
      hist_(std::make_unique<detail::Histogram<4, 8>>()),
      hist16_(std::make_unique<detail::Histogram<2, 8>>()) {
  if (max_count > 0xFFFFFFFFull) throw std::length_error("DepthSorter: at most 2^32 - 1 particles");
  if (options_.threads >= 2) helper_ = std::make_unique<Helper>();
}

DepthSorter::~DepthSorter() = default;

std::span<const std::uint32_t> DepthSorter::sort(const std::byte* records, std::size_t count, std::size_t stride,
                                                 const std::array<float, 16>& view_world, SortMode mode,
                                                 std::array<float, 2> near_far) {
  if (count > capacity_) throw std::length_error("DepthSorter::sort: more particles than the capacity");
  compute_depths(records, count, stride, depth_axis(view_world), depths_.get());
  return sort_depths({depths_.get(), count}, mode, near_far);
}

std::span<const std::uint32_t> DepthSorter::sort_depths(std::span<const float> depths, SortMode mode,
                                                        std::array<float, 2> near_far) {
  const std::size_t n = depths.size();
  if (n > capacity_) throw std::length_error("DepthSorter::sort_depths: more particles than the capacity");
  last_count_ = depths.data() == depths_.get() ? n : 0;  // depths() reports only what sort() computed
  std::uint32_t* out = indices_.get();
  if (mode == SortMode::None) {  // additive blending: any order, so the stored one
    for (std::size_t i = 0; i < n; ++i) out[i] = static_cast<std::uint32_t>(i);
    return {out, n};
  }
  std::uint64_t* items = items_.get();
  const float* d = depths.data();
  if (options_.quantize16) {
    const float range = near_far[1] - near_far[0];
    const float scale = range > 0 ? 1.0f / range : 0.0f;
    auto& h = *hist16_;
    h.clear();
    for (std::size_t i = 0; i < n; ++i) {
      items[i] = item16_for(d[i], static_cast<std::uint32_t>(i), mode, near_far[0], scale);
      h.add(static_cast<std::uint32_t>(items[i] >> 32));
    }
    detail::radix_scatter(items, scratch_.get(), n, h, out);
    return {out, n};
  }
  if (!helper_ || n < (1u << 16)) {  // small frames: a second thread costs more than it saves
    auto& h = *hist_;
    h.clear();
    for (std::size_t i = 0; i < n; ++i) {  // building the pairs and counting every digit: one pass
      items[i] = item_for(d[i], static_cast<std::uint32_t>(i), mode);
      h.add(static_cast<std::uint32_t>(items[i] >> 32));
    }
    detail::radix_scatter(items, scratch_.get(), n, h, out);
    return {out, n};
  }

  // Two threads: each builds and histograms its half, then for each digit both scatter their
  // half to offsets that keep the order stable (thread 0's items of a bucket before thread 1's).
  std::uint64_t* scratch = scratch_.get();
  std::uint32_t(*shared_hist)[kBuckets] = helper_->hist;
  const std::size_t half = n / 2;
  auto work = [&, shared_hist](int t) {
    const std::size_t begin = t == 0 ? 0 : half, end = t == 0 ? half : n;
    for (std::size_t i = begin; i < end; ++i) items[i] = item_for(d[i], static_cast<std::uint32_t>(i), mode);
    std::uint64_t* src = items;
    std::uint64_t* dst = scratch;
    for (int digit = 0; digit < kDigits; ++digit) {
      const int shift = 32 + digit * kBits;
      std::uint32_t* h = shared_hist[t];
      std::fill(h, h + kBuckets, 0u);
      for (std::size_t i = begin; i < end; ++i) ++h[(src[i] >> shift) & kMask];
      helper_->sync.arrive_and_wait();
      std::uint32_t offset[kBuckets];
      std::uint32_t sum = 0;
      for (std::uint32_t b = 0; b < kBuckets; ++b) {
        offset[b] = sum + (t == 1 ? shared_hist[0][b] : 0u);
        sum += shared_hist[0][b] + shared_hist[1][b];
      }
      if (digit == kDigits - 1) {
        for (std::size_t i = begin; i < end; ++i)
          out[offset[(src[i] >> shift) & kMask]++] = static_cast<std::uint32_t>(src[i]);
      } else {
        for (std::size_t i = begin; i < end; ++i) dst[offset[(src[i] >> shift) & kMask]++] = src[i];
        std::swap(src, dst);
      }
      helper_->sync.arrive_and_wait();  // every item is placed before the next digit reads them
    }
  };
  helper_->run(work);
  return {out, n};
}

std::span<const std::uint32_t> DepthSorter::sort_merged(std::span<const Source> sources, SortMode mode,
                                                        std::array<float, 2> near_far) {
  if (sources.size() > kMaxMergedSources) throw std::length_error("DepthSorter::sort_merged: too many sources");
  std::size_t base[kMaxMergedSources + 1] = {};
  for (std::size_t k = 0; k < sources.size(); ++k) {
    if (sources[k].count >= (std::size_t{1} << kMergedIndexBits))
      throw std::length_error("DepthSorter::sort_merged: source too large");
    base[k + 1] = base[k] + sources[k].count;
  }
  const std::size_t total = base[sources.size()];
  if (total > capacity_) throw std::length_error("DepthSorter::sort_merged: more particles than the capacity");
  for (std::size_t k = 0; k < sources.size(); ++k) {
    compute_depths(sources[k].records, sources[k].count, sources[k].stride, depth_axis(sources[k].view_world),
                   depths_.get() + base[k]);
  }
  const auto order = sort_depths({depths_.get(), total}, mode, near_far);
  std::uint32_t* out = indices_.get();
  for (std::size_t i = 0; i < order.size(); ++i) {  // global index -> (source, index)
    const std::size_t g = out[i];
    std::size_t k = 0;
    while (g >= base[k + 1]) ++k;
    out[i] = static_cast<std::uint32_t>(k << kMergedIndexBits | (g - base[k]));
  }
  return {out, total};
}

}  // namespace pstream::sort
