// The frame decoder, which decodes a clip's frames through its codec's unit (found in the
// registry, frame_codecs.cpp), and matching by id.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

#include <fmt/format.h>

#include "format/frame_unit.hpp"
#include "particlestream/codec.hpp"

namespace pstream::format {

FramePacket frame_packet(const Metadata& meta, std::uint64_t frame) {
  const FrameEntry& f = meta.frames[frame];
  return {f.packet_offset, f.packet_size, f.keyframe};
}

std::uint64_t keyframe_of(const Metadata& meta, std::uint64_t frame) {
  while (frame > 0 && !meta.frames[frame].keyframe) --frame;
  return frame;
}

std::uint64_t decode_start(const Metadata& meta, std::uint64_t frame, std::uint64_t last_decoded) {
  const std::uint64_t key = keyframe_of(meta, frame);
  return last_decoded != UINT64_MAX && last_decoded < frame && last_decoded >= key ? last_decoded + 1 : key;
}

namespace {

// The longest keyframe group of the clip, in frames.
std::uint64_t longest_group(const Metadata& meta) {
  std::uint64_t longest = 0, start = 0;
  for (std::uint64_t f = 0; f < meta.frame_count(); ++f) {
    if (meta.frames[f].keyframe) start = f;
    longest = std::max(longest, f - start + 1);
  }
  return longest;
}

}  // namespace

std::uint64_t FrameDecoder::base_state_bytes(const Metadata& meta) {
  const FrameCodecDecoding* codec = find_frame_codec(meta.codec.codec);
  return codec ? codec->state_bytes(meta) : 0;
}

std::uint64_t FrameDecoder::saved_state_bytes(const Metadata& meta) {
  const FrameCodecDecoding* codec = find_frame_codec(meta.codec.codec);
  return codec && longest_group(meta) > 2 ? codec->save_bytes(meta) : 0;
}

std::size_t FrameDecoder::saved_states_that_fit(const Metadata& meta, std::size_t wanted, std::uint64_t limit,
                                                std::uint64_t others) {
  const std::uint64_t each = saved_state_bytes(meta);
  if (each == 0 || wanted == 0) return 0;
  const std::uint64_t held = others + base_state_bytes(meta);
  return static_cast<std::size_t>(std::min<std::uint64_t>(wanted, limit > held ? (limit - held) / each : 0));
}

FrameDecoder::FrameDecoder(const Metadata& meta, std::string name, std::uint64_t memory_limit, std::size_t saved_states)
    : meta_(meta), name_(std::move(name)) {
  const std::uint64_t limit = memory_limit ? memory_limit : unbudgeted_memory_limit(meta);
  const FrameCodecDecoding* codec = find_frame_codec(meta.codec.codec);
  if (codec == nullptr)
    throw Error(fmt::format("{}: unknown frame codec {}", name_, static_cast<int>(meta.codec.codec)));
  // Saved states: more than the longest group's frames would never be used.
  save_bytes_ = saved_states > 0 ? saved_state_bytes(meta) : 0;
  if (save_bytes_ == 0) saved_states = 0;
  saved_states = std::min<std::uint64_t>(saved_states, longest_group(meta));
  const std::uint64_t saved_total = save_bytes_ * saved_states;
  const std::uint64_t needed = codec->state_bytes(meta) + saved_total;
  if (needed > limit) {
    throw OptionError(
        "budget",
        fmt::format("{}: max_count {} particles needs {:.1f} MiB of particle decoder state, more than {} "
                    "({:.1f} MiB); set a memory `budget` to allow it",
                    name_, meta.max_count, needed / 1048576.0,
                    memory_limit ? "the memory budget" : "the clip's stored bytes justify", limit / 1048576.0));
  }
  unit_ = codec->make_unit(meta_, name_);
  if (save_bytes_ != 0 && unit_->save_bytes() != save_bytes_)
    throw Error(fmt::format("{}: the {} codec saves {} bytes a state, not {}", name_, codec->name, unit_->save_bytes(),
                            save_bytes_));
  saved_.resize(saved_total);
  tags_.resize(saved_states);
  saves_.resize(saved_states);
  state_bytes_ = unit_->state_bytes() + saved_total;
}

FrameDecoder::~FrameDecoder() = default;

const FrameDecoder::Saved* FrameDecoder::saved_before(std::uint64_t frame) const {
  if (frame >= meta_.frame_count() || tags_.empty()) return nullptr;
  const std::uint64_t key = keyframe_of(meta_, frame);
  const Saved* best = nullptr;
  for (const Saved& t : tags_) {
    if (t.keyframe == key && t.frame < frame && (best == nullptr || t.frame > best->frame)) best = &t;
  }
  return best;
}

std::uint64_t FrameDecoder::resume_frame(std::uint64_t frame) const {
  const std::uint64_t start = decode_start(meta_, frame, last_);
  const Saved* saved = saved_before(frame);
  return saved != nullptr && saved->frame + 1 > start ? saved->frame + 1 : start;
}

bool FrameDecoder::can_decode(std::uint64_t frame) const {
  if (frame >= meta_.frame_count()) return false;
  if (meta_.frames[frame].keyframe || (last_ != UINT64_MAX && frame == last_ + 1)) return true;
  const Saved* saved = saved_before(frame);
  return saved != nullptr && saved->frame + 1 == frame;
}

void FrameDecoder::reset() {
  unit_->reset();
  last_ = UINT64_MAX;
}

std::size_t FrameDecoder::decode(std::uint64_t frame, std::span<const std::byte> packet, std::span<std::byte> out,
                                 std::span<MatchRun> matching) {
  if (!can_decode(frame)) {
    throw Error(fmt::format("{}: frame {} is predicted from frame {}, which was not decoded just before it", name_,
                            frame, frame == 0 ? 0 : frame - 1));
  }
  if (out.size() < meta_.frames[frame].count * meta_.record_size) {
    throw Error(
        fmt::format("{}: frame {}: {} bytes for {} records", name_, frame, out.size(), meta_.frames[frame].count));
  }
  const bool keyframe = meta_.frames[frame].keyframe;
  if (!keyframe && last_ + 1 != frame) {  // resume after a saved state
    const Saved* saved = saved_before(frame);
    const std::size_t slot = static_cast<std::size_t>(saved - tags_.data());
    unit_->restore(std::span(saved_).subspan(slot * save_bytes_, save_bytes_));
    keyframe_ = saved->keyframe;
  }
  last_ = UINT64_MAX;  // a failed decode leaves no reference
  const std::size_t runs = unit_->decode(frame, keyframe, packet, out, matching);
  last_ = frame;
  if (keyframe) keyframe_ = frame;
  if (target_ != kNoTarget && frame < target_ && !tags_.empty()) {
    if (!planned_) plan_saves(frame);  // the first decode on the way
    // (Decoding may have started again further on, after a state saved on the way.)
    while (save_count_ != 0 && saves_[save_count_ - 1].frame < frame) --save_count_;
    if (save_count_ != 0 && saves_[save_count_ - 1].frame == frame) {
      const std::size_t slot = saves_[--save_count_].slot;
      tags_[slot] = {};  // not a state until it is whole
      unit_->save(std::span(saved_).subspan(slot * save_bytes_, save_bytes_));
      tags_[slot] = {frame, keyframe_};
    }
  }
  return runs;
}

void FrameDecoder::set_target(std::uint64_t target) {
  if (target == target_) return;
  target_ = target;
  planned_ = false;
  save_count_ = 0;
}

// On the way to target_, decoding from `first` on: a state is worth keeping when a frame before the
// target will resume from it (after a frame of the target's group, two or more before it); every
// other slot is free. The first free one gets the frame halfway from the one before `first` to
// the target, the next halfway from there, and so on (saves_ is kept last first: decode() takes
// from its end).
void FrameDecoder::plan_saves(std::uint64_t first) {
  planned_ = true;
  save_count_ = 0;
  const std::uint64_t key = keyframe_of(meta_, target_), t = target_;
  std::uint64_t lo = first;  // one past the state decoding continues from
  for (std::size_t slot = 0; slot < tags_.size(); ++slot) {
    const Saved& tag = tags_[slot];
    if (tag.frame != UINT64_MAX && tag.keyframe == key && tag.frame + 2 <= t) continue;  // still useful
    const std::uint64_t mid = lo + (t - lo) / 2;  // (lo - 1 + t) / 2 rounded up, without lo - 1
    if (mid < lo || mid + 1 >= t) break;
    saves_[save_count_++] = {mid, slot};
    lo = mid + 1;
  }
  std::reverse(saves_.begin(), saves_.begin() + static_cast<std::ptrdiff_t>(save_count_));
}

// ---- Matching ----------------------------------------------------------------------------------

namespace {

template <class Id>
std::size_t merge_ids(std::uint32_t stride, std::uint32_t id_offset, const std::byte* a, std::uint64_t na,
                      const std::byte* b, std::uint64_t nb, std::span<MatchRun> out) {
  const auto id = [&](const std::byte* records, std::uint64_t i) {
    Id v;
    std::memcpy(&v, records + i * stride + id_offset, sizeof v);
    return v;
  };
  std::size_t n = 0;
  MatchRun run;
  bool open = false;  // `run` holds something
  // A keep after a drop or an insert starts a new run.
  const auto flush = [&] {
    if (!open) return true;
    if (n == out.size()) return false;
    out[n++] = run;
    run = {};
    open = false;
    return true;
  };
  std::uint64_t i = 0, j = 0;
  // Each frame's ids must strictly ascend: the last of each seen so far.
  bool have_a = false, have_b = false;
  Id last_a = 0, last_b = 0;
  while (i < na || j < nb) {
    const bool more_a = i < na, more_b = j < nb;
    const Id x = more_a ? id(a, i) : 0, y = more_b ? id(b, j) : 0;
    if ((more_a && have_a && x <= last_a) || (more_b && have_b && y <= last_b)) return kNoMatching;
    if (more_a && more_b && x == y) {
      if (run.drop != 0 || run.insert != 0) {
        if (!flush()) return kNoMatching;
      }
      ++run.keep, open = true;
      last_a = x, last_b = y, have_a = have_b = true;
      ++i, ++j;
    } else if (!more_b || (more_a && x < y)) {
      ++run.drop, open = true;
      last_a = x, have_a = true;
      ++i;
    } else {
      ++run.insert, open = true;
      last_b = y, have_b = true;
      ++j;
    }
  }
  if (!flush()) return kNoMatching;
  return n;
}

}  // namespace

std::size_t match_by_id(const Metadata& meta, std::span<const std::byte> prev, std::uint64_t prev_count,
                        std::span<const std::byte> cur, std::uint64_t cur_count, std::span<MatchRun> out) {
  const Attribute* id = meta.find("id");
  if (id == nullptr || id->components != 1) return kNoMatching;
  const std::uint64_t stride = meta.record_size;
  if (prev.size() < prev_count * stride || cur.size() < cur_count * stride) return kNoMatching;
  if (id->type == AttributeType::Uint64)
    return merge_ids<std::uint64_t>(meta.record_size, id->offset, prev.data(), prev_count, cur.data(), cur_count, out);
  if (id->type == AttributeType::Uint32)
    return merge_ids<std::uint32_t>(meta.record_size, id->offset, prev.data(), prev_count, cur.data(), cur_count, out);
  return kNoMatching;
}

}  // namespace pstream::format
