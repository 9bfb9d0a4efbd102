#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <utility>

#include <fmt/format.h>

#include "base/job_thread.hpp"
#include "base/names.hpp"
#include "particlestream/playback.hpp"
#include "playback/interpolate.hpp"

namespace pstream::playback {
namespace {

using Clock = std::chrono::steady_clock;
double ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

}  // namespace

struct Player::Clip {
  std::unique_ptr<stream::ParticleStream> stream;
  std::unique_ptr<sort::DepthSorter> sorter;
  std::int32_t color_offset = -1, velocity_offset = -1;
  render::Mat4 world = render::identity();
  std::unique_ptr<FrameBlender> blender;  // with interpolation (the CPU path)
  std::vector<std::byte> blended;         // an interpolated frame: up to both frames' particles
  // The GPU path: what the renderer makes the frame from, the pair table (room for both frames'
  // particles) and which pair of frames (and, unmatched, which side) it was made for.
  render::FramePair pair;
  std::vector<render::RecordLane> lanes;
  std::vector<render::ParticlePair> pairs;
  std::uint64_t pairs_a = ~0ull, pairs_b = ~0ull;
  int pairs_side = -1;
  std::uint64_t pairs_count = 0;
  PairCurves pair_curves;  // whether the pair of cached frames blends along curves (curves())
  // The table of the pair after this one (b and the frame after it), made ahead on the table
  // thread once that frame is decoded and matched: the renderer can move it to the GPU before the
  // playhead gets there.
  std::vector<render::ParticlePair> ahead_pairs;
  std::uint64_t ahead_a = ~0ull, ahead_b = ~0ull, ahead_count = 0, ahead_version = 0;
  std::uint64_t versions = 0;  // the last table version handed out
  // The next pair's table, made on the table thread into `ahead_pairs`.
  struct TableJob final : base::JobThread::Job {
    std::uint64_t a = 0, b = 0, na = 0, nb = 0, count = 0;
    std::span<const format::MatchRun> matching;  // the stream's, valid until its next update()
    std::span<render::ParticlePair> out;
    void run() override {
      bool nearer = false;
      count = pair_table(na, nb, &matching, 0.0, out, nearer);
    }
  };
  std::unique_ptr<TableJob> job;
  // Whether `f` to `next` moves along the curves through the velocities: Hermite interpolation,
  // the frames matched, and the velocities describing the matching (velocities_describe_matching(),
  // a sample of up to kMotionSample pairs), asked once a pair of cached frames.
  bool curves(Interpolation mode, const stream::FrameView& f, const stream::FrameView& next, bool matched,
              std::uint32_t record_size) {
    return matched && mode == Interpolation::Hermite && pair_curves(f.frame, next.frame, [&] {
             return velocities_describe_matching(f.first, next.first, next.matching, record_size, velocity_offset,
                                                 next.time - f.time);
           });
  }
  std::unique_ptr<std::atomic<std::uint32_t>> lent;  // FramePair::lent: 1 while a renderer reads ahead
  // Waits until the table thread and the renderer are done with what the stream lent them (the
  // frame ahead's records and matching): called before the stream moves, which may release them.
  void settle() const {
    if (job) job->wait();
    // The renderer only stores 0 (it cannot wake us without touching `lent` after we may have
    // moved on): polled, and in practice already 0, its copy taking a fraction of a host frame.
    while (lent && lent->load(std::memory_order_acquire) != 0)
      std::this_thread::sleep_for(std::chrono::microseconds(50));
  }
};

// The GPU path's table thread: a JobThread with room for every clip's job.
struct Player::TableThread : base::JobThread {
  using base::JobThread::JobThread;
};

namespace {
std::atomic<std::uint64_t> next_source{1};
}

Interpolation parse_interpolation(std::string_view name) {
  if (name == "none") return Interpolation::None;
  if (name == "linear") return Interpolation::Linear;
  if (name == "hermite") return Interpolation::Hermite;
  throw Error(fmt::format("`interpolation` '{}': expected none, linear or hermite{}", name,
                          did_you_mean(name, {"none", "linear", "hermite"})));
}

PlaybackPath parse_playback_path(std::string_view name) {
  if (name == "gpu") return PlaybackPath::Gpu;
  if (name == "cpu") return PlaybackPath::Cpu;
  throw Error(fmt::format("`playback` '{}': expected gpu or cpu{}", name, did_you_mean(name, {"gpu", "cpu"})));
}

Player::~Player() {
  for (const auto& c : clips_) c.settle();
  tables_.reset();
}

std::unique_ptr<Player> Player::open(std::span<const std::filesystem::path> files, PlayerOptions options) {
  if (files.empty()) throw Error("a player needs at least one clip");
  std::unique_ptr<Player> p(new Player());
  std::uint64_t total = 0;
  for (std::size_t i = 0; i < files.size(); ++i) {
    const std::filesystem::path& file = files[i];
    Clip c;
    stream::StreamOptions o;  // each clip its own (an IO backend is per file: the default one)
    o.cache_seconds = options.stream.cache_seconds;
    o.min_slots = options.stream.min_slots;
    o.max_slots = options.stream.max_slots;
    o.max_loads_in_flight = options.stream.max_loads_in_flight;
    o.decoded_frames = options.stream.decoded_frames;
    o.saved_states = options.stream.saved_states;
    // The GPU path stages the frame after next before the playhead gets there (FramePair::ahead):
    // one more decoded frame lets the IO worker decode it a whole cached frame ahead.
    if (options.path == PlaybackPath::Gpu && options.interpolation != Interpolation::None)
      o.decoded_frames = std::max<std::size_t>(o.decoded_frames, 4);
    o.blocking = options.stream.blocking;
    o.interpolate = options.interpolation != Interpolation::None;
    o.scheduler = options.stream.scheduler;
    o.budget = options.stream.budget;
    if (i < options.io.size()) o.io = std::move(options.io[i]);
    c.stream = stream::ParticleStream::open(file, std::move(o));
    const format::Metadata& m = c.stream->metadata();
    const std::uint64_t most = options.interpolation != Interpolation::None ? 2 * m.max_count : m.max_count;
    c.color_offset = color_offset(m);
    c.velocity_offset = velocity_offset(m);
    if (options.path == PlaybackPath::Cpu) {
      c.sorter = std::make_unique<sort::DepthSorter>(most, options.sorter);
      if (options.interpolation != Interpolation::None) {
        c.blender = std::make_unique<FrameBlender>(m);
        c.blended.resize(most * m.record_size);
      }
    } else {
      c.lanes = record_lanes(m);
      if (options.interpolation != Interpolation::None) {
        c.pairs.resize(most);
        c.ahead_pairs.resize(most);
        c.job = std::make_unique<Clip::TableJob>();
      }
      c.lent = std::make_unique<std::atomic<std::uint32_t>>(0);
      render::FramePair& fp = c.pair;
      fp.source = next_source.fetch_add(1);
      fp.record_size = m.record_size;
      fp.max_count = m.max_count;
      fp.lanes = c.lanes;
      fp.velocity_offset = c.velocity_offset;
      fp.color_offset = c.color_offset;
      fp.lent = c.lent.get();
    }
    c.stream->set_loop(options.loop);
    total += most;
    p->clips_.push_back(std::move(c));
  }
  p->interpolation_ = options.interpolation;
  p->path_ = options.path;
  if (p->clips_.size() > 1 && options.path == PlaybackPath::Cpu)
    p->merged_sorter_ = std::make_unique<sort::DepthSorter>(total, options.sorter);
  p->batches_.resize(p->clips_.size());
  p->sorted_by_.resize(p->clips_.size());  // reused every frame (a texture name is not copied again)
  p->sources_.reserve(p->clips_.size());
  if (options.path == PlaybackPath::Gpu && options.interpolation != Interpolation::None)
    p->tables_ = std::make_unique<TableThread>(p->clips_.size());
  return p;
}

std::size_t Player::clip_count() const { return clips_.size(); }
stream::ParticleStream& Player::clip(std::size_t i) { return *clips_.at(i).stream; }
const stream::ParticleStream& Player::clip(std::size_t i) const { return *clips_.at(i).stream; }
void Player::set_world_transform(std::size_t i, const render::Mat4& world) { clips_.at(i).world = world; }
const render::Mat4& Player::world_transform(std::size_t i) const { return clips_.at(i).world; }

void Player::play() {
  for (auto& c : clips_) c.stream->play();
}
void Player::pause() {
  for (auto& c : clips_) c.stream->pause();
}
void Player::stop() {
  for (auto& c : clips_) {
    c.settle();
    c.stream->stop();
  }
}
void Player::seek(double time) {
  for (auto& c : clips_) {
    c.settle();
    c.stream->seek(time);
  }
}
void Player::set_speed(double speed) {
  for (auto& c : clips_) {
    c.settle();
    c.stream->set_speed(speed);
  }
}
void Player::set_loop(bool loop) {
  for (auto& c : clips_) c.stream->set_loop(loop);
}
void Player::set_range(double start, double end) {
  for (auto& c : clips_) {
    c.settle();
    c.stream->set_range(start, end);
  }
}

std::uint64_t Player::max_frame_bytes() const {
  std::uint64_t total = 0;
  const std::uint64_t frames = interpolation_ != Interpolation::None ? 2 : 1;
  for (const auto& c : clips_) total += frames * c.stream->metadata().max_count * c.stream->metadata().record_size;
  return total;
}

const FrameStats& Player::advance(double dt, const render::Mat4& view, sort::SortMode mode) {
  stats_ = {};
  batch_count_ = 0;
  sources_.clear();
  merged_order_ = {};
  sort_mode_ = mode;
  sort_view_ = view;
  const bool sorting = mode != sort::SortMode::None && path_ == PlaybackPath::Cpu;
  const bool merge = sorting && merged_sorter_ && clips_.size() <= render::kMaxMergedBatches;
  for (auto& c : clips_) {
    const auto t0 = Clock::now();
    c.settle();  // (the renderer's copy of the frame ahead is done long before, in practice)
    c.stream->update(dt);
    if (c.stream->state() == stream::PlayState::Error) {  // it shows nothing; check() reports it
      ++stats_.failed_clips;
      continue;
    }
    const stream::FrameView f = c.stream->frame();
    render::ParticleBatch& b = batches_[batch_count_];
    b.first = f.first;
    b.second = {};  // decoded frames are contiguous (stream.hpp): sorting and drawing see one array
    b.count = f.count;
    b.order = {};
    auto t1 = Clock::now();
    stats_.stream_ms += ms(t0, t1);
    const format::Metadata& m = c.stream->metadata();
    if (path_ == PlaybackPath::Gpu) {
      if (!f.valid || f.count == 0) continue;
      b.count = gpu_pair(c, f);
      b.pair = &c.pair;
      b.first = {};
      b.record_size = m.record_size;
      b.color_offset = c.color_offset;
      b.velocity_offset = c.velocity_offset;
      b.world = c.world;
      stats_.particles += b.count;
      sorted_by_[batch_count_] = &c;
      ++batch_count_;
      continue;
    }
    b.pair = nullptr;
    if (interpolation_ != Interpolation::None && c.stream->fraction() > 0.0) {
      const stream::FrameView next = c.stream->next_frame();
      if (next.valid && f.valid) {
        // The stream matched the next frame's particles to this one's (by the codec or by id).
        const bool matched = next.matched && next.frame == f.frame + 1;
        if (!matched) ++stats_.unmatched_clips;
        const bool curves = c.curves(interpolation_, f, next, matched, m.record_size);
        const std::uint64_t n =
            c.blender->blend(b.first, f.count, next.first, next.count, matched ? &next.matching : nullptr,
                             c.stream->fraction(), next.time - f.time, curves, c.blended.data());
        b.first = std::span<const std::byte>(c.blended).first(n * m.record_size);
        b.count = n;
        const auto t2 = Clock::now();
        stats_.interpolate_ms += ms(t1, t2);
        t1 = t2;
      }
    }
    if (b.count == 0) continue;
    const std::uint64_t count = b.count;
    b.record_size = m.record_size;
    b.color_offset = c.color_offset;
    b.velocity_offset = c.velocity_offset;
    b.world = c.world;
    stats_.particles += count;
    if (sorting) {
      const render::Mat4 view_world = render::multiply(view, c.world);
      if (merge) {
        sources_.push_back({b.first.data(), count, b.record_size, view_world});
      } else {
        b.order = c.sorter->sort(b.first.data(), count, b.record_size, view_world, mode);
      }
    }
    stats_.sort_ms += ms(t1, Clock::now());
    sorted_by_[batch_count_] = &c;
    ++batch_count_;
  }
  if (merge && sources_.size() > 1) {
    const auto t0 = Clock::now();
    merged_order_ = merged_sorter_->sort_merged(sources_, mode);
    stats_.sort_ms += ms(t0, Clock::now());
  } else if (merge && sources_.size() == 1) {  // one clip with particles: its own order
    const auto t0 = Clock::now();
    batches_.front().order = sorted_by_[0]->sorter->sort(sources_[0].records, sources_[0].count, sources_[0].stride,
                                                         sources_[0].view_world, mode);
    stats_.sort_ms += ms(t0, Clock::now());
  }
  return stats_;
}

std::uint64_t Player::gpu_pair(Clip& c, const stream::FrameView& f) {
  render::FramePair& p = c.pair;
  p.a = f.first.first(f.count * p.record_size);
  p.a_frame = f.frame;
  p.a_count = f.count;
  p.b = {};
  p.pairs = {};
  p.ahead = {};
  p.ahead_pairs = {};
  p.t = 0.0;
  p.nearer = false;
  if (interpolation_ == Interpolation::None || c.stream->fraction() <= 0.0) return f.count;
  const stream::FrameView next = c.stream->next_frame();
  if (!next.valid) return f.count;
  const bool matched = next.matched && next.frame == f.frame + 1;
  if (!matched) ++stats_.unmatched_clips;
  const double t = c.stream->fraction();
  // The table changes with the pair of frames and, unmatched, with the nearer side: once per
  // cached frame, never between.
  const int side = matched ? 0 : (t < 0.5 ? 1 : 2);
  std::uint64_t& n = c.pairs_count;
  if (c.job && c.job->collect()) {  // (settle() waited for it)
    c.ahead_a = c.job->a;
    c.ahead_b = c.job->b;
    c.ahead_count = c.job->count;
    c.ahead_version = ++c.versions;
  }
  if (c.pairs_a != f.frame || c.pairs_b != next.frame || c.pairs_side != side) {
    if (matched && c.ahead_a == f.frame && c.ahead_b == next.frame) {  // made ahead: the renderer may hold it
      std::swap(c.pairs, c.ahead_pairs);
      n = c.ahead_count;
      p.pairs_version = c.ahead_version;
    } else {
      const auto t0 = Clock::now();
      bool nearer = false;
      n = pair_table(f.count, next.count, matched ? &next.matching : nullptr, t, c.pairs, nearer);
      p.pairs_version = ++c.versions;
      stats_.pair_table_ms += ms(t0, Clock::now());
    }
    c.ahead_a = c.ahead_b = ~0ull;
    c.pairs_a = f.frame;
    c.pairs_b = next.frame;
    c.pairs_side = side;
  }
  p.b = next.first.first(next.count * p.record_size);
  p.b_frame = next.frame;
  p.b_count = next.count;
  p.pairs = std::span<const render::ParticlePair>(c.pairs).first(n);
  p.t = t;
  p.dt = next.time - f.time;
  p.nearer = !matched;
  p.hermite = c.curves(interpolation_, f, next, matched, p.record_size);
  // The frame after `next`, once decoded, and (matched) the table from next to it, made on the
  // table thread and handed out from the host frame after it is done.
  const stream::FrameView after = c.stream->frame_after_next();
  if (after.valid) {
    p.ahead = after.first.first(after.count * p.record_size);
    p.ahead_frame = after.frame;
    p.ahead_count = after.count;
    if (after.matched && after.frame == next.frame + 1) {
      if ((c.ahead_a != next.frame || c.ahead_b != after.frame) && c.job->state() == Clip::TableJob::Idle) {
        Clip::TableJob& j = *c.job;
        j.a = next.frame;
        j.b = after.frame;
        j.na = next.count;
        j.nb = after.count;
        j.matching = after.matching;
        j.out = c.ahead_pairs;
        tables_->submit(j);
      } else if (c.ahead_a == next.frame && c.ahead_b == after.frame) {
        p.ahead_pairs = std::span<const render::ParticlePair>(c.ahead_pairs).first(c.ahead_count);
        p.ahead_pairs_version = c.ahead_version;
      }
    }
  }
  return n;
}

void Player::check() const {
  for (const auto& c : clips_) {
    if (c.stream->state() == stream::PlayState::Error) throw Error(c.stream->error());
  }
}

std::span<const render::ParticleBatch> Player::batches() const { return {batches_.data(), batch_count_}; }
std::span<const std::uint32_t> Player::merged_order() const { return merged_order_; }

std::ptrdiff_t Player::batch_of(std::size_t clip) const {
  for (std::size_t b = 0; b < batch_count_; ++b) {
    if (sorted_by_[b] == &clips_.at(clip)) return static_cast<std::ptrdiff_t>(b);
  }
  return -1;
}

}  // namespace pstream::playback
